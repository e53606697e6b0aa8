//! The `sdi` Debian package on a running system, inside the VM: the board
//! (the USB board emulator) is plugged in, udevd and the system bus run,
//! and `apt-get install ./sdi_*.deb` (offline: every dependency is
//! installed on the host, whose root the guest shares) has postinst create
//! the group, reload udev and re-trigger the board, which gets the group
//! and `SYSTEMD_WANTS=sdid.service`, and has the bus reload its policy.
//! v4l2loopback is loaded as at boot, from the package's modules-load.d
//! and modprobe.d files (/dev/video42, "SDI camera"); `sdictl status`
//! starts the packaged sdid by D-Bus activation (the guest has no systemd:
//! the bus runs the activation file's `Exec=` through its launch helper),
//! it drives the board and headless Chromium shows a frame of "SDI camera";
//! then it is stopped.
//! The hotplug start of `sdid.service` by a real systemd, and its feed of
//! a user's camera, are tests/tests/vm_systemd.rs.
//! The `sdi-pipewire-camera` package then installs beside it: in a user
//! session (PipeWire, WirePlumber, a session bus), the packaged sdid finds
//! the camera in /usr/libexec/sdi, whose node PipeWire lists as the camera
//! "SDI camera"; its purge leaves none of its files.
//! Then `apt-get remove` keeps the state directory and `apt-get purge`
//! removes it, saying so, and leaves no file of `dpkg -L sdi` behind.
//!
//! The guest's /usr is made writable (a throw-away overlay, like /etc and
//! /var) so that dpkg can install into it.

use std::fs;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use sdi_daemon::sink::pipewire::VIEW_NODE;
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::browser::{Browser, PageServer};
use sdi_tests::loopback;
use sdi_tests::package::{self, apt_get, gid_of};
use sdi_tests::pipewire;
use sdi_tests::process::{must, run, Reaped};
use sdi_tests::udev::{start_udevd, udevadm, usb_device, wait_initialized};
use sdi_tests::wait::wait_until;

const NAME: &str = "vm_apt_installs_activates_and_purges_the_package";
const SERIAL: &str = "EMU0005";
const BUS_NAME: &str = "org.sdi.Daemon";
const SYSTEM_BUS: &str = "/run/dbus/system_bus_socket";

#[test]
fn vm_apt_installs_activates_and_purges_the_package() {
    if crate::GUEST.on_host() {
        return;
    }
    in_vm();
}

fn busctl_system(args: &[&str]) -> Output {
    run(Command::new("busctl")
        .args(["--system", "--timeout=10"])
        .args(args))
}

fn bus_call(member: &str, args: &[&str]) -> String {
    let out = busctl_system(
        &[
            &[
                "call",
                "org.freedesktop.DBus",
                "/org/freedesktop/DBus",
                "org.freedesktop.DBus",
                member,
            ][..],
            args,
        ]
        .concat(),
    );
    String::from_utf8_lossy(&out.stdout).trim().to_owned()
}

/// The device node of a USB device (its DEVNAME).
fn device_node(dev: &Path) -> PathBuf {
    let out = must(udevadm().args(["info", "--query=property"]).arg(dev));
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("DEVNAME="))
        .map(PathBuf::from)
        .expect("USB device without DEVNAME")
}

fn properties(dev: &Path) -> String {
    let out = must(udevadm().args(["info", "--query=property"]).arg(dev));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Modules the package has loaded at boot (modules-load.d), loaded now as
/// systemd-modules-load would: plain modprobe, options from modprobe.d.
fn load_modules_as_at_boot() {
    let list = fs::read_to_string("/usr/lib/modules-load.d/sdi-v4l2loopback.conf").unwrap();
    for module in list
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        must(Command::new("modprobe").arg(module));
    }
}

/// The system bus as the dbus package runs it (`dbus-daemon --system`:
/// /usr/share/dbus-1/system.conf, the messagebus user, the launch helper).
fn start_system_bus(log: &Path) -> Reaped {
    fs::create_dir_all("/run/dbus").unwrap();
    let out = fs::File::create(log).unwrap();
    let child = Command::new("dbus-daemon")
        .args(["--system", "--nofork", "--nopidfile"])
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .expect("spawn dbus-daemon --system");
    let bus = Reaped(child);
    wait_until("the system bus", Duration::from_secs(30), || {
        Path::new(SYSTEM_BUS).exists()
    });
    bus
}

fn in_vm() {
    let Some(deb) = std::env::var_os("SDI_DEB").map(PathBuf::from) else {
        sdi_tests::skipped!("SKIPPED: {NAME}: the host could not build the package (above)");
        return;
    };
    let dir = Path::new("/tmp/sdi-package");
    fs::create_dir_all(dir).unwrap();
    let t_start = Instant::now();

    // The running system before the package: udevd, the system bus, the
    // board plugged in (no rule for it yet, no group sdi).
    let _udevd = start_udevd();
    let _bus = start_system_bus(&dir.join("dbus.log"));
    let emu = BoardEmulator::start("sdi0", SERIAL).expect("board emulator gadget");
    let mut dev = None;
    wait_until("the board enumerated", Duration::from_secs(30), || {
        dev = usb_device("0451", "9105");
        dev.is_some()
    });
    let dev = dev.unwrap();
    wait_initialized(&[&dev]);
    let node = device_node(&dev);
    assert!(gid_of("sdi").is_none(), "group sdi before the package");
    assert!(!properties(&dev).contains("SYSTEMD_WANTS"));
    assert!(
        !bus_call("ListActivatableNames", &[]).contains(BUS_NAME),
        "org.sdi.Daemon activatable before the package"
    );
    // man-db's dpkg trigger would rebuild the whole manual index under TCG
    // (minutes); this guest-only flag file turns that off.
    let _ = fs::remove_file("/var/lib/man-db/auto-update");

    // Install. The guest has no network: every dependency must already be
    // installed (not --no-download: apt 2.6 then cannot take a local .deb).
    let log = apt_get(&["install", deb.to_str().unwrap()]);
    assert!(!log.contains("sdi: purge"), "{log}");
    let listed = String::from_utf8_lossy(&must(Command::new("dpkg").args(["-L", "sdi"])).stdout)
        .into_owned();
    let files: Vec<&str> = listed.lines().filter(|p| !Path::new(p).is_dir()).collect();
    eprintln!("dpkg -L sdi: {} files", files.len());
    assert!(files.contains(&"/usr/bin/sdid"), "{listed}");

    // postinst: the group, and udev re-ran the new rules on the board.
    let sdi_gid = gid_of("sdi").expect("postinst did not create the group sdi");
    wait_until(
        "the board's node to get the group sdi (postinst's udev trigger)",
        Duration::from_secs(30),
        || fs::metadata(&node).is_ok_and(|m| m.gid() == sdi_gid),
    );
    let meta = fs::metadata(&node).unwrap();
    assert_eq!(
        meta.permissions().mode() & 0o777,
        0o660,
        "{}",
        node.display()
    );
    let props = properties(&dev);
    assert!(
        props.lines().any(|l| l == "SYSTEMD_WANTS=sdid.service"),
        "{props}"
    );
    assert!(props.contains(":systemd:"), "{props}");
    // The bus reloaded its configuration: the activation file is seen.
    assert!(
        bus_call("ListActivatableNames", &[]).contains(BUS_NAME),
        "org.sdi.Daemon not activatable after the install"
    );

    // v4l2loopback as at boot: the package's node and label.
    load_modules_as_at_boot();
    package::assert_view_node();

    // The administrator's configuration: the emulated board.
    package::configure_emulated_board(SERIAL);

    // D-Bus activation starts the packaged sdid on the board.
    let t_activate = Instant::now();
    let mut status = None;
    wait_until(
        "sdictl status to start sdid by activation",
        Duration::from_secs(120),
        || {
            let out = run(Command::new("/usr/bin/sdictl").args(["--json", "status"]));
            status = out
                .status
                .success()
                .then(|| serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap());
            status.is_some()
        },
    );
    let status = status.unwrap();
    eprintln!(
        "sdid activated and answering after {:.1} s: {status}",
        t_activate.elapsed().as_secs_f64()
    );
    assert_eq!(status["Backend"], "opt8241", "{status}");
    let pid: i32 = bus_call("GetConnectionUnixProcessID", &["s", BUS_NAME])
        .strip_prefix("u ")
        .and_then(|p| p.trim().parse().ok())
        .expect("pid of org.sdi.Daemon");
    let exe = fs::read_link(format!("/proc/{pid}/exe")).unwrap();
    assert_eq!(exe, Path::new("/usr/bin/sdid"), "owner of {BUS_NAME}");

    // The loopback view node is a capture device once sdid streams.
    let view = Path::new("/dev/video42");
    wait_until(
        "/dev/video42 to be a capture device",
        Duration::from_secs(60),
        || loopback::advertises_capture(view),
    );
    // Chromium sees the camera.
    let server = PageServer::start();
    let browser = Browser::chromium(&server.url, dir);
    let first =
        server.first_view_frame("chromium", Duration::from_secs(240), || browser.log_tail());
    eprintln!(
        "chromium: first frame of SDI camera {:.1} s after its start",
        browser.started.elapsed().as_secs_f64()
    );
    server.assert_opened_view("chromium", "SDI camera", &first);
    drop(browser);
    drop(server);

    // prerm stops the service through systemd, which the guest lacks: stop
    // the activated sdid here.
    stop(pid);

    drop(emu);

    if let Some(camera) = std::env::var_os("SDI_CAMERA_DEB") {
        camera_package(Path::new(&camera));
    }

    // What the service and the administrator leave in place.
    fs::create_dir_all("/var/lib/sdi").unwrap();
    fs::write("/var/lib/sdi/calibration.toml", "# test\n").unwrap();
    fs::write("/var/lib/sdi/run.sdirec", b"SDIREC").unwrap();

    // remove: the package's files go, the state stays; the bus forgets sdid.
    let log = apt_get(&["remove", "sdi"]);
    assert!(!log.contains("sdi: purge"), "{log}");
    for f in &files {
        assert!(!Path::new(f).exists(), "{f} still there after remove");
    }
    assert!(
        Path::new("/var/lib/sdi/run.sdirec").is_file(),
        "remove took the recordings"
    );
    assert!(
        !bus_call("ListActivatableNames", &[]).contains(BUS_NAME),
        "org.sdi.Daemon still activatable after remove"
    );

    // purge: the state directory goes too, and says so.
    let log = apt_get(&["purge", "sdi"]);
    assert!(
        log.contains("sdi: purge: removing /var/lib/sdi (2 files"),
        "purge said:\n{log}"
    );
    assert!(
        !Path::new("/var/lib/sdi").exists(),
        "purge left /var/lib/sdi"
    );
    for f in &files {
        assert!(!Path::new(f).exists(), "{f} still there after purge");
    }
    // The package's own directories go too (shared ones such as /usr/bin
    // stay), but /etc/sdi, which holds the administrator's file.
    for d in listed
        .lines()
        .filter(|d| d.ends_with("/sdi") && *d != "/etc/sdi")
    {
        assert!(!Path::new(d).exists(), "{d} left behind");
    }
    // The administrator's file is all that is left of /etc/sdi; the group
    // stays (see packaging/debian/postrm).
    let etc: Vec<String> = fs::read_dir("/etc/sdi")
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(etc, ["sdid.toml"]);
    assert!(gid_of("sdi").is_some());
    let status = run(Command::new("dpkg-query").args(["-W", "-f=${Status}", "sdi"]));
    let status = String::from_utf8_lossy(&status.stdout);
    assert!(
        status.is_empty() || status.contains("not-installed"),
        "dpkg still knows sdi: {status}"
    );
    eprintln!(
        "package installed, activated, started by hotplug, shown in Chromium and purged in {:.1} s",
        t_start.elapsed().as_secs_f64()
    );
}

/// The PipeWire camera package in a user session: installed beside sdi,
/// started by the packaged sdid from /usr/libexec/sdi, listed by PipeWire
/// as a camera, purged without a trace.
fn camera_package(deb: &Path) {
    let t0 = Instant::now();
    apt_get(&["install", deb.to_str().unwrap()]);
    let listed = String::from_utf8_lossy(
        &must(Command::new("dpkg").args(["-L", "sdi-pipewire-camera"])).stdout,
    )
    .into_owned();
    let files: Vec<&str> = listed.lines().filter(|p| !Path::new(p).is_dir()).collect();
    assert!(
        files.contains(&"/usr/libexec/sdi/sdi-pipewire-camera"),
        "{listed}"
    );
    {
        let s = pipewire::Session::start();
        let _sdid = Reaped(
            s.command("/usr/bin/sdid")
                .args(["--bus-address", &s.bus.address, "--backend", "sim"])
                .args(["--sink", "pipewire", "--frame-rate-hz", "15"])
                .env("RUST_LOG", "info")
                .spawn()
                .expect("start the packaged sdid"),
        );
        let node = sdi_tests::wait::wait_for(
            "the packaged camera's sdi-camera node",
            Duration::from_secs(120),
            || s.node(VIEW_NODE),
        );
        // Frames through the packaged camera are read by vm_systemd
        // (and on the host, tests/tests/pipewire_camera.rs); here only
        // that the packaged sdid finds the packaged camera.
        assert_eq!(node["media.class"], "Video/Source", "{node:?}");
        assert_eq!(node["media.role"], "Camera", "{node:?}");
        assert_eq!(node["node.description"], "SDI camera (raw)", "{node:?}");
    }
    apt_get(&["purge", "sdi-pipewire-camera"]);
    for f in &files {
        assert!(!Path::new(f).exists(), "{f} still there after purge");
    }
    eprintln!(
        "camera package installed, listed by PipeWire as a camera and purged in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
}

/// SIGTERM to `pid`, then SIGKILL if it has not ended after 15 s. (The
/// activated sdid's parent is gone; nobody reaps it here, so "ended" is a
/// zombie.)
fn stop(pid: i32) {
    let running = || {
        fs::read_to_string(format!("/proc/{pid}/stat"))
            .is_ok_and(|s| s.rsplit(") ").next().is_some_and(|r| !r.starts_with('Z')))
    };
    let pid = Pid::from_raw(pid);
    let _ = kill(pid, Signal::SIGTERM);
    let deadline = Instant::now() + Duration::from_secs(15);
    while running() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    if running() {
        eprintln!("sdid did not end on SIGTERM in 15 s: SIGKILL");
        let _ = kill(pid, Signal::SIGKILL);
    }
}
