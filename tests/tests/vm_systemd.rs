//! The system service under a real systemd (issue 32's system service
//! case) on Debian 13, the release users have now: the VM boots trixie's
//! kernel 6.12 and systemd 257 as PID 1 (`vmrun -S -r`): udevd, logind,
//! the system bus and the users' managers run as on a desktop. The `sdi`
//! and `sdi-pipewire-camera` packages (built on the host, as for Debian 12)
//! are installed with dpkg; their udev rules link the loopback nodes into
//! /dev/v4l/by-id by card label, never a hostile label's (issue 46). A
//! member of the group sdi is logged in (lingering), so their systemd runs
//! PipeWire 1.4, WirePlumber 0.5 with SDI's rule, and the packaged user
//! unit `sdi-pipewire-camera.service`, which waits for a system sdid.
//! Then the board is plugged in: udev tags
//! it, systemd starts `sdid.service` from the device's `SYSTEMD_WANTS`
//! with the unit's whole sandbox, and that sdid feeds the user's camera:
//! PipeWire lists one SDI camera (media.role Camera; the rule hides the
//! loopback nodes) and `sdictl doctor`, run by the user, says so and names
//! PipeWire's version; `pipewiresrc` run as the user reads 30 frames the
//! camera published, in two modes; ffmpeg reads the loopback node
//! (v4l2loopback 0.15 from DKMS) through its by-id link, which `sdictl
//! list` names; headless Chromium run as the user opens the camera
//! through the user's camera portal and follows a mode switch.
//! Killed, sdid is restarted by systemd (`Restart=on-failure`) and the
//! camera, which kept its node, delivers again. Then the other order: the
//! user logs out and in again while sdid runs, and the camera delivers.
//! Last, `dpkg --purge` leaves no file of either package. (Debian 13's
//! lintian checks the packages on the host: `package_deb`.)

use std::fs;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use sdi_daemon::sink::pipewire::{SYSTEM_FEED_NAME, VIEW_NODE};
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::browser::{stats_rgb, view_frame_like, Browser, PageServer};
use sdi_tests::capture;
use sdi_tests::clients::{self, off_by};
use sdi_tests::package::{self, gid_of};
use sdi_tests::pipewire::{self, camera_mode, Clients, FrameLog};
use sdi_tests::process::{must, run};
use sdi_tests::vm::{self, Guest, Userland};
use sdi_tests::wait::{wait_for, wait_for_or, wait_until};
use v4l2loopback_glue::{create_device, remove_device, CreateOptions, GlueError};

const NAME: &str = "vm_systemd_starts_sdid_on_hotplug_and_it_feeds_a_users_camera";
const SERIAL: &str = "EMU0007";
const USER: &str = "sdi-user";
const UID: u32 = 4242;
/// Where the test and the user's camera write (mode 0777).
const SCRATCH: &str = "/tmp/sdi-systemd";
/// How far (per channel, 0-255) a frame Chromium drew may be from the
/// snapshot's mean: YUV to RGB, and frames taken at other times.
const TOLERANCE: f64 = 12.0;

/// The systemd guest on Debian 13, the release users have now (PipeWire
/// 1.4, WirePlumber 0.5, systemd 257; tests/README.md says why this guest):
/// Chromium needs more than the plain guest's RAM.
static GUEST: Guest = Guest::new(&[(NAME, 900)])
    .on(Userland::Debian13)
    .with_systemd()
    .with_mem_mb(vm::DESKTOP_MEM_MB)
    .prepared_by(prepare);

/// The packages, both of them: the user's camera is the packaged one.
fn prepare() -> bool {
    package::export_for_vm(NAME).is_some_and(|debs| debs.camera.is_some())
}

#[test]
fn vm_systemd_starts_sdid_on_hotplug_and_it_feeds_a_users_camera() {
    if GUEST.on_host() {
        return;
    }
    in_vm();
}

fn systemctl(args: &[&str]) -> String {
    let out = run(Command::new("systemctl").args(args));
    String::from_utf8_lossy(&out.stdout).trim().to_owned()
}

fn unit_property(unit: &str, property: &str) -> String {
    systemctl(&["show", "-p", property, "--value", unit])
}

fn journal(unit: &str) -> String {
    let out = run(Command::new("journalctl").args(["--no-pager", "-o", "cat", "-u", unit]));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `sdictl doctor`, run by the user, finds their PipeWire (its version as
/// the guest's `pipewire --version` says it: 1.4 on Debian 13) listing one
/// SDI camera that can be read.
fn doctor_sees_one_readable_camera(user: &Clients) {
    let out = run(user.command("/usr/bin/sdictl").args(["doctor", "--json"]));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("doctor --json is not JSON ({e}): {out:?}"));
    let pipewire = report["checks"]
        .as_array()
        .and_then(|a| a.iter().find(|c| c["id"] == "pipewire"))
        .unwrap_or_else(|| panic!("no pipewire check: {report}"));
    let installed = String::from_utf8_lossy(&run(Command::new("pipewire").arg("--version")).stdout)
        .lines()
        .find_map(|l| {
            l.strip_prefix("Compiled with libpipewire ")
                .map(str::to_owned)
        })
        .expect("pipewire --version");
    let summary = pipewire["summary"].as_str().unwrap_or_default();
    eprintln!(
        "MEASURED: doctor as {USER}: [{}] {summary}",
        pipewire["status"]
    );
    assert_eq!(pipewire["status"], "ok", "{pipewire}");
    assert!(
        summary.contains(&format!("PipeWire {installed} lists one SDI camera")),
        "doctor names PipeWire {installed}: {summary}"
    );
}

/// `sdictl` (the package's) on the system bus, as root.
fn sdictl(args: &[&str]) -> Output {
    run(Command::new("/usr/bin/sdictl").args(args))
}

/// `sdictl set-mode mode`, then the mean colour of the view frame in it.
fn set_mode_expect(mode: &str, dir: &Path) -> [f64; 3] {
    let (w, h) = package::EMULATED_BOARD_PX;
    clients::set_mode_view_mean(sdictl, mode, &dir.join("snap.png"), w, h)
}

/// Headless Chromium, run as the user with the PipeWire camera
/// (`WebRtcPipeWireCamera`), opens "SDI camera (MODE)" through the camera
/// portal of the user's session and shows what the system sdid publishes:
/// a frame like `sdictl snapshot` of depth-edge, then, after `sdictl
/// set-mode separation`, one like separation's. The portal and the
/// permission store are the user's, started by D-Bus activation as units
/// of their manager; the camera permission is stored beforehand and the
/// portal backend that would ask the user never has to run
/// (`pipewire::TEST_PORTAL`, for the desktop `pipewire::TEST_DESKTOP`).
fn chromium_through_the_portal(user: &Clients, scratch: &Path, camera_log: &FrameLog) {
    let t0 = Instant::now();
    let portals = pipewire::test_portals_dir(scratch);
    // The manager's environment is what the D-Bus activated portal gets.
    must(user.command("systemctl").args([
        "--user",
        "set-environment",
        &format!("XDG_CURRENT_DESKTOP={}", pipewire::TEST_DESKTOP),
        &format!("XDG_DESKTOP_PORTAL_DIR={}", portals.display()),
    ]));
    user.grant_camera();
    let portal_log = || journal_of_user_unit("xdg-desktop-portal.service");
    user.wait_camera_portal(portal_log);
    let dir = scratch.join("browser");
    fs::create_dir_all(&dir).unwrap();
    fs::set_permissions(&dir, fs::Permissions::from_mode(0o777)).unwrap();
    let expected = set_mode_expect("depth-edge", &dir);

    let server = PageServer::start();
    let browser = Browser::chromium_pipewire(&server.url, &dir, user);
    let first = server.first_view_frame("chromium", Duration::from_secs(480), || {
        // The camera's own lines (not one per frame): its streams' states,
        // formats and clients, beside Chromium's side of the same stream.
        let camera: Vec<String> = camera_log
            .text()
            .lines()
            .filter(|l| pipewire::parse_published(l).is_none())
            .map(str::to_owned)
            .collect();
        format!(
            "{}\n{}\n{}\nportal:\n{}\nWirePlumber:\n{}\nthe camera's log:\n{}",
            browser.fatal_errors(),
            browser.log_lines("video_capture"),
            browser.log_tail(),
            portal_log(),
            journal_tail_of_user_unit("wireplumber.service", 20),
            camera[camera.len().saturating_sub(40)..].join("\n")
        )
    });
    eprintln!(
        "MEASURED: Chromium as {USER}, through the user's portal: first frame {:.1} s after \
         its start ({:.1} s with the portal)",
        browser.started.elapsed().as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
    // Any mode in the label: Debian 12's PipeWire (0.3.65) gives a client
    // the description the node had when it was made (here raw), not the
    // current one; the frames say which mode it shows.
    server.assert_opened_view("chromium", "SDI camera (", &first);
    let (i, v) = server.wait_for(
        &format!("chromium: a depth-edge frame near {expected:.1?}"),
        0,
        Duration::from_secs(60),
        |v| view_frame_like(v, expected, TOLERANCE),
    );
    eprintln!(
        "MEASURED: chromium: depth-edge frame mean {:.1?} (snapshot {expected:.1?})",
        stats_rgb(&v, "mean")
    );
    // Separation: the emulated board's raw and depth-edge (one colour map)
    // and bipolar-colour look too alike to tell apart.
    let t_switch = Instant::now();
    let expected_other = set_mode_expect("separation", &dir);
    assert!(
        off_by(expected, expected_other) > 2.0 * TOLERANCE,
        "modes too alike to tell apart: {expected:?} {expected_other:?}"
    );
    let (_, v) = server.wait_for(
        &format!("chromium: a separation frame near {expected_other:.1?}"),
        i + 1,
        Duration::from_secs(60),
        |v| view_frame_like(v, expected_other, TOLERANCE),
    );
    eprintln!(
        "MEASURED: chromium: set-mode separation seen after {:.1} s: mean {:.1?} (snapshot \
         {expected_other:.1?})",
        t_switch.elapsed().as_secs_f64(),
        stats_rgb(&v, "mean")
    );
}

/// The last `lines` lines of [`journal_of_user_unit`].
fn journal_tail_of_user_unit(unit: &str, lines: usize) -> String {
    let log = journal_of_user_unit(unit);
    let all: Vec<&str> = log.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

/// The journal of `unit`, a unit of a user's manager.
fn journal_of_user_unit(unit: &str) -> String {
    let out = run(Command::new("journalctl")
        .args(["--no-pager", "-o", "cat"])
        .arg(format!("_SYSTEMD_USER_UNIT={unit}")));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

const USER_UNITS: [&str; 3] = [
    "pipewire.service",
    "wireplumber.service",
    "sdi-pipewire-camera.service",
];

/// The user logs in (lingering: their manager runs without a terminal);
/// returns once it runs PipeWire, WirePlumber and the SDI camera.
fn log_in(user: &Clients) {
    let t = Instant::now();
    must(Command::new("loginctl").args(["enable-linger", USER]));
    wait_until(
        "the user's PipeWire, WirePlumber and SDI camera units",
        Duration::from_secs(180),
        || {
            let out = run(user
                .command("systemctl")
                .args(["--user", "is-active"])
                .args(USER_UNITS));
            String::from_utf8_lossy(&out.stdout)
                .lines()
                .filter(|l| *l == "active")
                .count()
                == USER_UNITS.len()
        },
    );
    eprintln!(
        "MEASURED: the user's manager ran {USER_UNITS:?} {:.1} s after the login",
        t.elapsed().as_secs_f64()
    );
}

/// The user's manager and everything it ran end.
fn log_out() {
    must(Command::new("loginctl").args(["disable-linger", USER]));
    must(Command::new("systemctl").args(["stop", &format!("user@{UID}.service")]));
    wait_until("the user's manager to end", Duration::from_secs(60), || {
        systemctl(&["is-active", &format!("user@{UID}.service")]) != "active"
    });
}

fn in_vm() {
    let t_start = Instant::now();
    let exe = fs::read_link("/proc/1/exe").unwrap();
    assert!(exe.ends_with("systemd"), "PID 1 is {}", exe.display());
    for unit in [
        "systemd-udevd.service",
        "dbus.service",
        "systemd-logind.service",
    ] {
        assert_eq!(systemctl(&["is-active", unit]), "active", "{unit}");
    }
    let scratch = Path::new(SCRATCH);
    fs::create_dir_all(scratch).unwrap();
    fs::set_permissions(scratch, fs::Permissions::from_mode(0o777)).unwrap();

    // The packages, as on a desktop (man-db's trigger would rebuild the
    // manual index for minutes under TCG; this guest-only file turns it off).
    let _ = fs::remove_file("/var/lib/man-db/auto-update");
    let debs: Vec<String> = ["SDI_DEB", "SDI_CAMERA_DEB"]
        .iter()
        .map(|v| std::env::var(v).unwrap_or_else(|_| panic!("{v} from the host side")))
        .collect();
    // dpkg rather than apt: apt's resolver reads the host's whole package
    // lists over 9p (vm_desktop/package installs with apt).
    let t_install = Instant::now();
    must(Command::new("dpkg").arg("--install").args(&debs));
    eprintln!(
        "MEASURED: dpkg --install of both packages: {:.1} s",
        t_install.elapsed().as_secs_f64()
    );
    let sdi_gid = gid_of("sdi").expect("postinst made the group sdi");
    // v4l2loopback as at boot: systemd-modules-load reads the package's
    // modules-load.d (options from its modprobe.d).
    must(Command::new("systemctl").args(["restart", "systemd-modules-load.service"]));
    package::assert_view_node();
    loopback_by_id_links();
    package::configure_emulated_board(SERIAL);

    // A member of the group sdi logs in (lingering: their manager runs
    // without a terminal). The camera unit's log goes to a file the test
    // reads, with every published frame's CRC.
    must(Command::new("useradd").args([
        "--create-home",
        "--uid",
        &UID.to_string(),
        "--groups",
        // video: the camera nodes' group, as a desktop's seat user has
        // them (uaccess); so the user's WirePlumber can open the loopback
        // nodes, and only SDI's rule keeps them out of PipeWire.
        "sdi,video",
        USER,
    ]));
    let camera_log = FrameLog::file(scratch.join("camera.log"));
    let dropin = Path::new("/etc/systemd/user/sdi-pipewire-camera.service.d");
    fs::create_dir_all(dropin).unwrap();
    fs::write(
        dropin.join("test-log.conf"),
        format!(
            "[Service]\nEnvironment=RUST_LOG=info,sdi_pipewire_camera=debug,sdid::pipewire::frames=trace\n\
             StandardError=append:{}\n",
            camera_log.path().display()
        ),
    )
    .unwrap();
    let user = Clients::user(USER, UID, scratch);
    log_in(&user);
    assert_eq!(systemctl(&["is-active", "sdid.service"]), "inactive");

    // The board is plugged in: udev and systemd start sdid.service.
    let t_plug = Instant::now();
    let emu = BoardEmulator::start("sdi0", SERIAL).expect("board emulator gadget");
    wait_until(
        "systemd to start sdid.service for the board",
        Duration::from_secs(180),
        || systemctl(&["is-active", "sdid.service"]) == "active",
    );
    eprintln!(
        "MEASURED: sdid.service active (bus name taken) {:.1} s after the board was plugged in",
        t_plug.elapsed().as_secs_f64()
    );
    let wanted_by = unit_property("sdid.service", "WantedBy");
    assert!(
        wanted_by
            .split_whitespace()
            .any(|u| u.trim_matches('"').ends_with(".device")),
        "sdid.service not wanted by the board's device unit: WantedBy={wanted_by}"
    );
    let main_pid = unit_property("sdid.service", "MainPID");
    assert_eq!(
        fs::read_link(format!("/proc/{main_pid}/exe")).unwrap(),
        Path::new("/usr/bin/sdid")
    );
    // RuntimeDirectory= (root:sdi 0750) and UMask=: the feed's socket is the
    // group's only.
    let feed_dir = Path::new("/run/sdi");
    let m = fs::metadata(feed_dir).unwrap();
    assert_eq!((m.uid(), m.gid(), m.mode() & 0o777), (0, sdi_gid, 0o750));
    let m = fs::metadata(feed_dir.join(SYSTEM_FEED_NAME)).unwrap();
    assert_eq!((m.uid(), m.gid(), m.mode() & 0o777), (0, sdi_gid, 0o660));

    // The user's camera, fed by the system sdid: one SDI camera.
    let node = wait_for(
        "the fed camera's node in the user's PipeWire",
        Duration::from_secs(120),
        || user.node(VIEW_NODE),
    );
    assert_eq!(node["media.role"], "Camera", "{node:?}");
    // Never suspended (see the camera's node properties): WirePlumber
    // 0.5's suspend landing on Chromium's reopened link failed it.
    assert_eq!(node[pipewire::SUSPEND_TIMEOUT_KEY], 0, "{node:?}");
    let cameras = user.sdi_cameras();
    assert_eq!(cameras.len(), 1, "one SDI camera: {cameras:?}");
    eprintln!(
        "MEASURED: one SDI camera in the user's PipeWire {:.1} s after the plug",
        t_plug.elapsed().as_secs_f64()
    );
    doctor_sees_one_readable_camera(&user);
    let read = |mode: &str, what: &str| {
        let t = Instant::now();
        let frame_bytes = 640 * 480 * 2;
        let yuyv = user.read_frames(
            VIEW_NODE,
            "video/x-raw,format=YUY2,width=640,height=480",
            30,
            Duration::from_secs(180),
        );
        assert_eq!(yuyv.len(), 30 * frame_bytes, "30 whole frames");
        let crcs = pipewire::frame_crcs(&yuyv, frame_bytes);
        camera_log.assert_published(&crcs, VIEW_NODE, "YUYV", mode, what);
        eprintln!(
            "MEASURED: {what}: pipewiresrc as {USER} read 30 frames the camera published \
             in mode {mode}, in {:.1} s",
            t.elapsed().as_secs_f64()
        );
    };
    read(
        &camera_mode(&node).expect("a mode in the description"),
        "hotplug",
    );
    let out = sdictl(&["set-mode", "depth-edge"]);
    assert!(out.status.success(), "set-mode: {out:?}");
    wait_for(
        "the fed camera to follow the mode",
        Duration::from_secs(60),
        || {
            user.node(VIEW_NODE)
                .filter(|p| camera_mode(p).as_deref() == Some("depth-edge"))
        },
    );
    read("depth-edge", "after a mode switch");
    // `sdictl list` names the view node's by-id link, and ffmpeg reads
    // the node through it.
    let out = sdictl(&["--json", "list"]);
    let list: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("sdictl --json list ({e}): {out:?}"));
    assert_eq!(
        list["cameras"][0]["links"],
        serde_json::json!(["/dev/v4l/by-id/sdi-view"]),
        "{list}"
    );
    let view = Path::new("/dev/v4l/by-id/sdi-view");
    let frames = capture::read_frames(view, 3, "rgb24", &scratch.join("ffmpeg-view.rgb"))
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(!frames.is_empty(), "no frame from {}", view.display());
    chromium_through_the_portal(&user, scratch, &camera_log);

    // sdid dies: systemd starts it again, the camera kept its node and
    // delivers again.
    let t_kill = Instant::now();
    let restarts: u32 = unit_property("sdid.service", "NRestarts")
        .parse()
        .expect("NRestarts");
    must(Command::new("systemctl").args(["kill", "--signal=KILL", "sdid.service"]));
    wait_until(
        "systemd to restart sdid.service",
        Duration::from_secs(120),
        || {
            unit_property("sdid.service", "NRestarts") == (restarts + 1).to_string()
                && systemctl(&["is-active", "sdid.service"]) == "active"
        },
    );
    assert_ne!(unit_property("sdid.service", "MainPID"), main_pid);
    eprintln!(
        "MEASURED: sdid killed, restarted by systemd and active again in {:.1} s",
        t_kill.elapsed().as_secs_f64()
    );
    // The restarted sdid starts in its configured mode.
    let node = wait_for(
        "the fed camera's node after the restart",
        Duration::from_secs(60),
        || user.node(VIEW_NODE),
    );
    read(
        &camera_mode(&node).expect("a mode in the description"),
        "after systemd restarted sdid",
    );
    assert_eq!(
        user.sdi_cameras().len(),
        1,
        "one SDI camera after the restart"
    );

    // The other order: sdid runs, then the user logs in again.
    log_out();
    log_in(&user);
    let node = wait_for(
        "the fed camera's node after a new login",
        Duration::from_secs(120),
        || user.node(VIEW_NODE),
    );
    assert_eq!(
        user.sdi_cameras().len(),
        1,
        "one SDI camera after a new login"
    );
    read(
        &camera_mode(&node).expect("a mode in the description"),
        "logged in with sdid running",
    );

    let sdid_log = journal("sdid.service");
    assert!(
        !sdid_log.contains("panicked"),
        "sdid's journal:\n{sdid_log}"
    );
    loopback_node_without_the_camera_package(&user);
    drop(emu);
    eprintln!(
        "MEASURED: installed, logged in, hotplug-started, fed, restarted in {:.1} s",
        t_start.elapsed().as_secs_f64()
    );
    log_out();
    purge_leaves_nothing();
}

/// The package's `70-sdi-loopback.rules` under trixie's udevd (issue 46):
/// the lone view node "SDI camera" is `/dev/v4l/by-id/sdi-view`; nodes
/// created at run time (0.15's control device) labelled "SDI camera sim-0"
/// and "SDI data sim-0" get `sdi-sim-0-view` and `sdi-sim-0-data`, and
/// hostile labels ("..", '/', spaces, a leading dot) get no link anywhere
/// in /dev. Removing the nodes removes their links. All before the user
/// logs in: their PipeWire would list the extra nodes as cameras.
fn loopback_by_id_links() {
    let t = Instant::now();
    let by_id = Path::new("/dev/v4l/by-id");
    let target = |name: &str| fs::canonicalize(by_id.join(name)).ok();
    let sdi_links = || -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(by_id)
            .map(|d| {
                d.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.starts_with("sdi-"))
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        names
    };
    wait_for_or(
        "/dev/v4l/by-id/sdi-view -> /dev/video42",
        Duration::from_secs(60),
        || (target("sdi-view").as_deref() == Some(Path::new("/dev/video42"))).then_some(()),
        || format!("{:?}", sdi_links()),
    );
    let labels = [
        "SDI camera sim-0",
        "SDI data sim-0",
        "SDI camera ../x",
        "SDI camera a/b",
        "SDI camera a b",
        "SDI data .hidden",
    ];
    let nodes: Vec<_> = labels
        .iter()
        .map(|l| create_device(&CreateOptions::new(l)).unwrap_or_else(|e| panic!("{l}: {e}")))
        .collect();
    must(Command::new("udevadm").args(["settle", "--timeout=60"]));
    let want = ["sdi-sim-0-data", "sdi-sim-0-view", "sdi-view"];
    wait_for_or(
        "the by-id links of the sim-0 nodes",
        Duration::from_secs(60),
        || (sdi_links() == want).then_some(()),
        || format!("{:?}", sdi_links()),
    );
    assert_eq!(target("sdi-sim-0-view").as_ref(), Some(&nodes[0].path));
    assert_eq!(target("sdi-sim-0-data").as_ref(), Some(&nodes[1].path));
    // Every link in /dev to a node of a hostile label (but udev's own
    // /dev/char/MAJOR:MINOR, which every node has).
    let hostile: Vec<&Path> = nodes[2..].iter().map(|n| n.path.as_path()).collect();
    let mut stray = Vec::new();
    links_into(Path::new("/dev"), &hostile, &mut stray);
    assert!(
        stray.is_empty(),
        "links to the hostile labels' nodes: {stray:?}"
    );
    for node in &nodes {
        // udev's v4l_id may still hold a node open for a moment.
        wait_until(
            "the node's removal",
            Duration::from_secs(60),
            || match remove_device(node) {
                Ok(()) => true,
                Err(GlueError::Busy { .. }) => false,
                Err(e) => panic!("removing {}: {e}", node.path.display()),
            },
        );
    }
    must(Command::new("udevadm").args(["settle", "--timeout=60"]));
    wait_for_or(
        "the sim-0 links to go with their nodes",
        Duration::from_secs(60),
        || (sdi_links() == ["sdi-view"]).then_some(()),
        || format!("{:?}", sdi_links()),
    );
    eprintln!(
        "MEASURED: by-id links: sdi-view, sdi-sim-0-view, sdi-sim-0-data made, {} hostile \
         labels without a link, links gone with their nodes, in {:.1} s",
        hostile.len(),
        t.elapsed().as_secs_f64()
    );
}

/// The symbolic links under `dir` (not under /dev/char) that resolve to
/// one of `nodes`, into `found`.
fn links_into(dir: &Path, nodes: &[&Path], found: &mut Vec<String>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let Ok(meta) = fs::symlink_metadata(&path) else {
            continue;
        };
        if meta.file_type().is_symlink() {
            let to = fs::canonicalize(&path).ok();
            if to.as_deref().is_some_and(|t| nodes.contains(&t)) && !dir.ends_with("char") {
                found.push(format!("{} -> {:?}", path.display(), to));
            }
        } else if meta.is_dir() {
            links_into(&path, nodes, found);
        }
    }
}

/// Without the camera package (its program and WirePlumber rule gone),
/// PipeWire 1.4 lists the loopback view node itself as the SDI camera and
/// reads it (PipeWire reads v4l2loopback from 1.3.81; docs/loopback.md):
/// pipewiresrc gets whole frames, and `sdictl doctor` says the one SDI
/// camera can be read. With the package, the rule hides the node and the
/// camera process's node is the one camera (above): one camera either way.
fn loopback_node_without_the_camera_package(user: &Clients) {
    run(user
        .command("systemctl")
        .args(["--user", "stop", "sdi-pipewire-camera.service"]));
    must(Command::new("dpkg").args(["--purge", "sdi-pipewire-camera"]));
    assert!(!Path::new("/usr/libexec/sdi/sdi-pipewire-camera").exists());
    // WirePlumber's linking decisions in its journal, for a failed read.
    run(user.command("systemctl").args([
        "--user",
        "set-environment",
        "WIREPLUMBER_DEBUG=3,s-linking:4,s-node:4",
    ]));
    run(user
        .command("systemctl")
        .args(["--user", "restart", "wireplumber.service"]));
    let t = Instant::now();
    let camera = wait_for_or(
        "PipeWire to list the loopback view node as the SDI camera",
        Duration::from_secs(120),
        || {
            let cameras = user.sdi_cameras();
            (cameras.len() == 1
                && cameras[0]
                    .get("api.v4l2.cap.card")
                    .and_then(|v| v.as_str())
                    .is_some_and(|c| c.starts_with("SDI camera")))
            .then(|| cameras[0].clone())
        },
        || {
            let video: Vec<String> = user
                .nodes()
                .iter()
                .filter(|p| {
                    p.get("media.class")
                        .and_then(|v| v.as_str())
                        .is_some_and(|c| c.starts_with("Video"))
                })
                .map(|p| format!("{p:?}"))
                .collect();
            format!(
                "the user's video nodes:\n{}\nWirePlumber's log:\n{}",
                video.join("\n"),
                journal_of_user_unit("wireplumber.service")
            )
        },
    );
    let name = camera["node.name"].as_str().expect("node.name").to_owned();
    let frame_bytes = 640 * 480 * 2;
    let read = || {
        user.try_read_frames(
            &name,
            "video/x-raw,format=YUY2,width=640,height=480",
            30,
            Duration::from_secs(180),
        )
    };
    let tail = |unit: &str| journal_tail_of_user_unit(unit, 80);
    let fail = |e: String| -> ! {
        panic!(
            "{e}\nthe node when found: id {}\nWirePlumber's log:\n{}\nPipeWire's log:\n{}",
            camera
                .get("object.id")
                .map_or("?".into(), |v| v.to_string()),
            tail("wireplumber.service"),
            tail("pipewire.service")
        )
    };
    let yuyv = match read() {
        Ok(frames) => frames,
        // PipeWire 1.4.2 sometimes takes the first link of the freshly
        // made v4l2 node back to idle and suspended within ~60 ms of
        // streaming and negotiates it again (WirePlumber's log: running,
        // idle, suspended; PipeWire's: the link "negotiating -> error");
        // pipewiresrc 1.4.2 cannot take a second format (it drops its
        // possible caps after the first, gstpipewiresrc.c) and fails with
        // "unhandled format". Seen in 3 of 12 runs here, and in a plain
        // guest without systemd. That is the reader's limit, not the node's:
        // the node is read once more, and must then give 30 frames.
        Err(e) if e.contains("unhandled format") => {
            let pipewire = tail("pipewire.service");
            if !pipewire.contains("Format negotiation failed") {
                fail(e);
            }
            eprintln!(
                "MEASURED: the first pipewiresrc on {name} ended in PipeWire's renegotiation \
                 (pipewiresrc 1.4.2 takes one format only); reading again"
            );
            read().unwrap_or_else(|e| fail(e))
        }
        Err(e) => fail(e),
    };
    assert_eq!(yuyv.len(), 30 * frame_bytes, "30 whole frames of {name}");
    eprintln!(
        "MEASURED: without the camera package: PipeWire lists the loopback node {name} as the one \
         SDI camera and pipewiresrc read 30 frames of it, {:.1} s after WirePlumber's restart",
        t.elapsed().as_secs_f64()
    );
    doctor_sees_one_readable_camera(user);
}

/// `dpkg --purge` of the packages while sdid runs: the service stops, and
/// no file of either package and no state is left; the administrator's
/// `/etc/sdi/sdid.toml` stays.
fn purge_leaves_nothing() {
    let files: Vec<String> = ["sdi"]
        .iter()
        .flat_map(|p| {
            String::from_utf8_lossy(&run(Command::new("dpkg-query").args(["-L", p])).stdout)
                .lines()
                .map(str::to_owned)
                .collect::<Vec<_>>()
        })
        .filter(|f| Path::new(f).is_file())
        .collect();
    assert!(files.len() > 5, "the packages' files: {files:?}");
    must(Command::new("dpkg").args(["--purge", "sdi"]));
    assert_ne!(systemctl(&["is-active", "sdid.service"]), "active");
    let left: Vec<&String> = files.iter().filter(|f| Path::new(f).exists()).collect();
    assert!(left.is_empty(), "files left after the purge: {left:?}");
    assert!(
        !Path::new("/var/lib/sdi").exists(),
        "/var/lib/sdi left after the purge"
    );
    // What the administrator wrote (not the package's) stays, as dpkg
    // leaves every file it does not own.
    let etc: Vec<String> = fs::read_dir("/etc/sdi")
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    assert_eq!(etc, ["sdid.toml"], "/etc/sdi after the purge");
    eprintln!("MEASURED: purged: none of the {} files left", files.len());
}
