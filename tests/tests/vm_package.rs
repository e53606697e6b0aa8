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
//! Hotplug (issue 32's system service case): a user session runs PipeWire,
//! WirePlumber with SDI's rule and its camera (`--system-feed`, as the user
//! unit runs it); the board is plugged in again, udev's add event names
//! `sdid.service` (SYSTEMD_WANTS), which the test starts from the installed
//! unit as systemd would (the guest has no systemd:
//! `start_as_systemd_would` says what is applied and what not). That sdid
//! feeds the session's camera: one SDI camera in PipeWire, pipewiresrc reads
//! 30 frames the camera published, in two modes, ffmpeg still reads the
//! loopback node; with `SDI_PORTAL_CHROMIUM` set, headless Chromium
//! through the camera portal is to open "SDI camera (MODE)" and draw a
//! frame (not yet seen to pass).
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
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use sdi_daemon::sink::pipewire::VIEW_NODE;
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::browser::{Browser, PageServer};
use sdi_tests::loopback;
use sdi_tests::package;
use sdi_tests::pipewire;
use sdi_tests::process::{must, run, Reaped};
use sdi_tests::udev::{start_udevd, udevadm, usb_device, wait_initialized, UsbMonitor};
use sdi_tests::vm;
use sdi_tests::wait::wait_until;

const NAME: &str = "vm_apt_installs_activates_and_purges_the_package";
const SERIAL: &str = "EMU0005";
const BUS_NAME: &str = "org.sdi.Daemon";
const SYSTEM_BUS: &str = "/run/dbus/system_bus_socket";

#[test]
fn vm_apt_installs_activates_and_purges_the_package() {
    if !vm::in_vm() {
        if vm::unavailable_reason().is_some() {
            // Prints why it skips (or fails under SDI_REQUIRE_VM).
            vm::run_test_in_vm(NAME, 1200);
            return;
        }
        let Some(debs) = package::debs() else { return };
        std::env::set_var("SDI_DEB", &debs.sdi);
        match &debs.camera {
            Some(camera) => std::env::set_var("SDI_CAMERA_DEB", camera),
            None => {
                let why = "no sdi-pipewire-camera package: the camera program was not built \
                           (cargo build -p sdi-pipewire-camera, which needs libpipewire-0.3-dev \
                           libspa-0.2-dev clang libclang-dev)";
                assert!(
                    std::env::var_os("SDI_REQUIRE_VM").is_none(),
                    "{why}, and SDI_REQUIRE_VM is set"
                );
                sdi_tests::skipped!("SKIPPED: the camera package's part of {NAME}: {why}");
            }
        }
        // Chromium needs more than the default 1 GiB.
        std::env::set_var("VMRUN_MEM", "2560");
        std::env::set_var(
            "VMRUN_APPEND",
            "vmrun.overlays=/tmp,/var,/etc,/root,/home,/usr",
        );
        vm::run_test_in_vm(NAME, 1200);
        return;
    }
    in_vm();
}

/// `apt-get ARGS`, non-interactive, output echoed; asserts success and
/// returns stdout and stderr together (maintainer scripts write to either).
/// The guest runs the test in a chroot of the host's root, where udevadm
/// ignores requests (right for a real chroot); SYSTEMD_IGNORE_CHROOT tells
/// the maintainer scripts' udevadm that this one is the running system.
fn apt_get(args: &[&str]) -> String {
    let t0 = Instant::now();
    let out = run(Command::new("apt-get")
        .args(["-y", "-o", "Dpkg::Use-Pty=0"])
        .args(args)
        .env("DEBIAN_FRONTEND", "noninteractive")
        .env("SYSTEMD_IGNORE_CHROOT", "1"));
    eprintln!("apt-get {args:?}: {:.1} s", t0.elapsed().as_secs_f64());
    assert!(
        out.status.success(),
        "apt-get {args:?} failed ({})",
        out.status
    );
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
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

fn gid_of(group: &str) -> Option<u32> {
    let out = run(Command::new("getent").args(["group", group]));
    String::from_utf8_lossy(&out.stdout)
        .split(':')
        .nth(2)
        .and_then(|g| g.trim().parse().ok())
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
    let deb = PathBuf::from(std::env::var_os("SDI_DEB").expect("SDI_DEB from the host side"));
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
    let name = fs::read_to_string("/sys/class/video4linux/video42/name")
        .expect("no /dev/video42 from the package's modprobe.d options");
    assert_eq!(name.trim(), "SDI camera");

    // The administrator's configuration: the emulated board, small and
    // slow enough for TCG beside Chromium.
    fs::write(
        "/etc/sdi/sdid.toml",
        format!(
            "frame_rate_hz = 15.0\nexposure_us = 2000.0\n\
             [board]\nserial = \"{SERIAL}\"\nroi = [0, 0, 64, 48]\n"
        ),
    )
    .unwrap();

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

    // The board plugged in again starts sdid.service as udev asks, and it
    // feeds the PipeWire camera of a user session (Chromium through the
    // portal among its readers).
    hotplug_feeds_a_session(&emu, view, sdi_gid, dir);
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

/// Set (on the host) to read the fed camera with Chromium through the
/// camera portal too.
const PORTAL_CHROMIUM: &str = "SDI_PORTAL_CHROMIUM";

/// Where the package puts the system units.
const SYSTEM_UNITS: &str = "/usr/lib/systemd/system";

/// The `[Service]` settings of the installed unit `name`, as (key, value)
/// in file order.
fn service_settings(name: &str) -> Vec<(String, String)> {
    let path = Path::new(SYSTEM_UNITS).join(name);
    let text = fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut section = "";
    let mut settings = Vec::new();
    for line in text.lines().map(str::trim) {
        if line.starts_with('[') {
            section = line;
        } else if section == "[Service]" && !line.starts_with('#') {
            if let Some((k, v)) = line.split_once('=') {
                settings.push((k.to_owned(), v.to_owned()));
            }
        }
    }
    settings
}

/// A command line of a unit (`ExecStart=`...) without systemd's prefixes
/// (`+` full privileges, `-` failure ignored, ...), split into words (the
/// package's units quote nothing).
fn unit_command(line: &str) -> Vec<String> {
    line.trim_start_matches(['+', '-', '@', '!', ':'])
        .split_whitespace()
        .map(str::to_owned)
        .collect()
}

/// A service started the way systemd starts it for udev's
/// `SYSTEMD_WANTS=` (the guest has no systemd; see
/// [`start_as_systemd_would`]).
struct Service {
    child: std::process::Child,
    log: PathBuf,
    /// `RuntimeDirectory=` as made.
    runtime_dir: Option<PathBuf>,
}

impl Service {
    /// `systemctl stop`: SIGTERM, at most `TimeoutStopSec=` (15 s) to end,
    /// and a clean exit.
    fn stop(mut self) {
        let _ = kill(Pid::from_raw(self.child.id() as i32), Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(15);
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                assert!(
                    status.success(),
                    "sdid ended with {status} on SIGTERM; its log:\n{}",
                    fs::read_to_string(&self.log).unwrap_or_default()
                );
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        panic!("sdid did not end in 15 s of SIGTERM");
    }
}

/// Starts the installed unit `name` (Type=dbus) as systemd does, from its
/// file: `ExecStart=` with a clean environment, `Group=` and `UMask=`,
/// `RuntimeDirectory=` (made root:Group with its mode, passed as
/// `RUNTIME_DIRECTORY`), `StateDirectory=` and `ConfigurationDirectory=`
/// likewise; ready once it owns `BusName=` on the system bus, then
/// `ExecStartPost=`. Not applied: the sandbox (namespaces, capability
/// bounding, device policy, system call filter), the journal, cgroups.
fn start_as_systemd_would(name: &str, log: &Path) -> Service {
    let settings = service_settings(name);
    let get = |key: &str| {
        settings
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.clone())
    };
    assert_eq!(get("Type").as_deref(), Some("dbus"), "{name}");
    let group = get("Group").expect("Group=");
    let gid = gid_of(&group).unwrap_or_else(|| panic!("no group {group}"));
    let mut env = vec![(
        "PATH".to_owned(),
        "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin".to_owned(),
    )];
    let mut runtime_dir = None;
    for (key, root, var) in [
        ("RuntimeDirectory", "/run", "RUNTIME_DIRECTORY"),
        ("StateDirectory", "/var/lib", "STATE_DIRECTORY"),
        ("ConfigurationDirectory", "/etc", "CONFIGURATION_DIRECTORY"),
    ] {
        let Some(dir) = get(key) else { continue };
        let path = Path::new(root).join(&dir);
        fs::create_dir_all(&path).unwrap();
        let mode = get(&format!("{key}Mode")).unwrap_or_else(|| "0755".to_owned());
        let mode = u32::from_str_radix(&mode, 8).expect("an octal mode");
        fs::set_permissions(&path, fs::Permissions::from_mode(mode)).unwrap();
        // systemd gives the runtime and state directories to the unit's
        // user and group, the configuration directory stays root's.
        if var != "CONFIGURATION_DIRECTORY" {
            nix::unistd::chown(&path, None, Some(nix::unistd::Gid::from_raw(gid))).unwrap();
        }
        env.push((var.to_owned(), path.display().to_string()));
        if var == "RUNTIME_DIRECTORY" {
            runtime_dir = Some(path);
        }
    }
    let exec = unit_command(&get("ExecStart").expect("ExecStart="));
    let umask = get("UMask").unwrap_or_else(|| "0022".to_owned());
    let out = fs::File::create(log).unwrap();
    let child = Command::new("/bin/sh")
        .args(["-c", &format!("umask {umask} && exec \"$@\""), "sh"])
        .args(&exec)
        .env_clear()
        .envs(env)
        .gid(gid)
        .stdin(std::process::Stdio::null())
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .unwrap_or_else(|e| panic!("start {exec:?}: {e}"));
    let service = Service {
        child,
        log: log.to_owned(),
        runtime_dir,
    };
    let bus_name = get("BusName").expect("BusName=");
    let t0 = Instant::now();
    while !bus_call("NameHasOwner", &["s", &bus_name]).contains("true") {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "{name} did not take {bus_name} in 120 s; its log:\n{}",
            fs::read_to_string(log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let owner: u32 = bus_call("GetConnectionUnixProcessID", &["s", &bus_name])
        .strip_prefix("u ")
        .and_then(|p| p.trim().parse().ok())
        .expect("pid of the bus name");
    assert_eq!(
        owner,
        service.child.id(),
        "{bus_name} owned by another sdid"
    );
    for post in settings.iter().filter(|(k, _)| k == "ExecStartPost") {
        let prefix: String = post
            .1
            .chars()
            .take_while(|c| "+-@!:".contains(*c))
            .collect();
        let ignore_failure = prefix.contains('-');
        let cmd = unit_command(&post.1);
        let out = run(Command::new(&cmd[0])
            .args(&cmd[1..])
            .env("SYSTEMD_IGNORE_CHROOT", "1"));
        assert!(
            out.status.success() || ignore_failure,
            "ExecStartPost {cmd:?}: {out:?}"
        );
    }
    service
}

/// Issue 32's system service case: the user session runs PipeWire and
/// its camera (`sdi-pipewire-camera --system-feed`, as the user unit runs
/// it, with SDI's WirePlumber rule as the camera package installs it),
/// dialing `/run/sdi`; the board is plugged in again, udev's event names
/// `sdid.service` (`SYSTEMD_WANTS`), which is started from its installed
/// unit as systemd would ([`start_as_systemd_would`]); that root sdid
/// feeds the session: PipeWire lists one SDI camera, `sdi-camera` with
/// media.role Camera, `pipewiresrc` reads 30 frames the camera published
/// from the feed, in two modes, ffmpeg still reads the loopback node, and
/// (opt-in, [`PORTAL_CHROMIUM`]) Chromium through the camera portal reads
/// a frame of it.
fn hotplug_feeds_a_session(emu: &BoardEmulator, view: &Path, sdi_gid: u32, dir: &Path) {
    let Some(program) = pipewire::camera_program() else {
        eprintln!("no camera program built: the system feed is not checked");
        return;
    };
    let t0 = Instant::now();
    let rules = sdi_tests::process::repo_root().join("udev/wireplumber");
    let installed = [
        ("51-sdi-v4l2.lua", "/usr/share/wireplumber/main.lua.d"),
        (
            "51-sdi-v4l2.conf",
            "/usr/share/wireplumber/wireplumber.conf.d",
        ),
    ];
    for (file, dir) in installed {
        fs::create_dir_all(dir).unwrap();
        fs::copy(rules.join(file), Path::new(dir).join(file)).unwrap();
    }
    {
        let s = pipewire::Session::start();
        let log = pipewire::FrameLog::file(s.dir.path().join("camera.log"));
        let _camera = Reaped(
            s.command(&program)
                .arg(sdi_daemon::sink::pipewire::SYSTEM_FEED_FLAG)
                .env("RUST_LOG", "info,sdid::pipewire::frames=trace")
                .stderr(log.writer())
                .spawn()
                .expect("start the camera with --system-feed"),
        );

        // Hotplug: the board comes back; udev names the unit to start.
        let mut monitor = UsbMonitor::start();
        emu.unplug().expect("unplug the board");
        wait_until("the board gone", Duration::from_secs(30), || {
            usb_device("0451", "9105").is_none()
        });
        emu.plug().expect("plug the board in");
        let t_plug = Instant::now();
        let mut event = None;
        wait_until(
            "udev's add event of the board",
            Duration::from_secs(60),
            || {
                event = monitor.events().into_iter().find(|e| {
                    e.get("ACTION").map(String::as_str) == Some("add")
                        && e.contains_key("ID_SDI_BOARD")
                });
                event.is_some()
            },
        );
        monitor.stop();
        let event = event.unwrap();
        assert!(
            event.get("TAGS").is_some_and(|t| t.contains(":systemd:")),
            "{event:?}"
        );
        let wants = event.get("SYSTEMD_WANTS").cloned().unwrap_or_default();
        assert_eq!(wants, "sdid.service", "the board's add event: {event:?}");
        let sdid = start_as_systemd_would(&wants, &dir.join("sdid-hotplug.log"));
        eprintln!(
            "hotplug: {wants} answering on the system bus {:.1} s after the board's add event",
            t_plug.elapsed().as_secs_f64()
        );
        // RuntimeDirectory= and Group=/UMask= made the feed's directory and
        // socket reachable by the group sdi only.
        let feed_dir = sdid.runtime_dir.clone().expect("RuntimeDirectory=");
        let m = fs::metadata(&feed_dir).unwrap();
        assert_eq!((m.uid(), m.gid(), m.mode() & 0o777), (0, sdi_gid, 0o750));
        let m = fs::metadata(feed_dir.join(sdi_daemon::sink::pipewire::SYSTEM_FEED_NAME)).unwrap();
        assert_eq!((m.uid(), m.gid(), m.mode() & 0o777), (0, sdi_gid, 0o660));

        let node = sdi_tests::wait::wait_for(
            "the fed camera's sdi-camera node",
            Duration::from_secs(120),
            || s.node(VIEW_NODE),
        );
        assert_eq!(node["media.role"], "Camera", "{node:?}");
        let sdi_cameras: Vec<_> = s
            .nodes()
            .into_iter()
            .filter(|p| {
                let text = |k: &str| p.get(k).and_then(|v| v.as_str()).unwrap_or("").to_owned();
                p.get("media.role").and_then(|v| v.as_str()) == Some("Camera")
                    && (text("node.name").starts_with("sdi-")
                        || text("node.description").contains("SDI")
                        || text("api.v4l2.cap.card").contains("SDI"))
            })
            .collect();
        assert_eq!(sdi_cameras.len(), 1, "one SDI camera: {sdi_cameras:?}");

        // Frames through the fed camera, each one it published, in the
        // system sdid's mode and after a switch, which only the feed tells it.
        let read = |mode: &str| {
            let t = Instant::now();
            let frame_bytes = 640 * 480 * 2;
            let yuyv = s.read_frames(
                VIEW_NODE,
                "video/x-raw,format=YUY2,width=640,height=480",
                30,
                Duration::from_secs(180),
            );
            assert_eq!(yuyv.len(), 30 * frame_bytes, "30 whole frames");
            let crcs = pipewire::frame_crcs(&yuyv, frame_bytes);
            log.assert_published(
                &crcs,
                VIEW_NODE,
                "YUYV",
                mode,
                "pipewiresrc on the fed camera",
            );
            eprintln!(
                "system feed: pipewiresrc read 30 frames the camera published in mode {mode}, in {:.1} s",
                t.elapsed().as_secs_f64()
            );
        };
        let mode = |p: &std::collections::HashMap<String, serde_json::Value>| {
            p["node.description"]
                .as_str()
                .and_then(|d| d.strip_prefix("SDI camera ("))
                .and_then(|d| d.strip_suffix(')'))
                .map(str::to_owned)
        };
        read(&mode(&node).expect("a mode in the description"));
        let out = run(Command::new("/usr/bin/sdictl").args(["set-mode", "depth-edge"]));
        assert!(out.status.success(), "set-mode: {out:?}");
        sdi_tests::wait::wait_for(
            "the fed camera to follow the mode",
            Duration::from_secs(60),
            || {
                s.node(VIEW_NODE)
                    .filter(|p| mode(p).as_deref() == Some("depth-edge"))
            },
        );
        read("depth-edge");
        let ffmpeg = run(Command::new("timeout")
            .args([
                "120",
                "ffmpeg",
                "-hide_banner",
                "-loglevel",
                "error",
                "-nostdin",
            ])
            .args(["-f", "v4l2", "-i"])
            .arg(view)
            .args(["-frames:v", "3", "-f", "null", "-"]));
        assert!(
            ffmpeg.status.success(),
            "ffmpeg on {}: {ffmpeg:?}",
            view.display()
        );
        eprintln!(
            "system feed: one SDI camera in the user session, 2 x 30 frames, the mode followed, ffmpeg on the loopback node, in {:.1} s",
            t0.elapsed().as_secs_f64()
        );

        // Chromium through the camera portal, as a desktop's browser: only
        // with SDI_PORTAL_CHROMIUM set. Its first run here (a loaded host)
        // got no page report in 480 s; not yet seen to pass.
        match pipewire::CameraPortal::missing() {
            _ if std::env::var_os(PORTAL_CHROMIUM).is_none() => eprintln!(
                "system feed: Chromium through the portal not run ({PORTAL_CHROMIUM} unset)"
            ),
            Some(why) => {
                assert!(
                    std::env::var_os("SDI_REQUIRE_VM").is_none(),
                    "Chromium through the portal needs {why}, and SDI_REQUIRE_VM is set"
                );
                sdi_tests::skipped!(
                    "SKIPPED: Chromium through the portal on the fed camera: {why}"
                );
            }
            None => {
                let t_chromium = Instant::now();
                let _portal = pipewire::CameraPortal::start(&s);
                let bdir = s.dir.path().join("browser");
                fs::create_dir_all(&bdir).unwrap();
                let server = PageServer::start();
                let browser = Browser::chromium_pipewire(&server.url, &bdir, &s);
                let first = server.first_view_frame("chromium", Duration::from_secs(480), || {
                    format!(
                        "{}\n{}\nportal log:\n{}",
                        browser.log_lines("video_capture"),
                        browser.log_tail(),
                        fs::read_to_string(s.dir.path().join("portal.log")).unwrap_or_default()
                    )
                });
                eprintln!(
                    "system feed: Chromium through the portal, first frame {:.1} s after its start ({:.1} s with the portal)",
                    browser.started.elapsed().as_secs_f64(),
                    t_chromium.elapsed().as_secs_f64()
                );
                server.assert_opened_view("chromium", "SDI camera (depth-edge)", &first);
            }
        }
        sdid.stop();
    }
    for (file, dir) in installed {
        let _ = fs::remove_file(Path::new(dir).join(file));
    }
    eprintln!(
        "hotplug and the system feed: {:.1} s",
        t0.elapsed().as_secs_f64()
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
        // Frames through the camera are read by hotplug_feeds_a_session
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
