//! Helpers for D-Bus integration tests: a private `dbus-daemon` per test,
//! `sdid` on it, and `sdictl` pointed at it.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use nix::sys::signal::Signal;

use crate::process::Reaped;
use crate::sdid_command::SdidCommand;
use crate::wait::{wait_for, wait_until};

/// `target/<profile>` of the running test binary.
pub(crate) fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test exe path");
    // target/<profile>/deps/<test>-<hash>
    exe.parent()
        .and_then(Path::parent)
        .expect("target dir")
        .to_owned()
}

/// Path of `sdid` or `sdictl` for a test, under its real name.
///
/// Design: the tests need the programs as separate processes (exit codes,
/// signals, stderr, other users, the VM guest, activation and unit files),
/// and they must not run `cargo build` from inside themselves. Cargo builds
/// the bins of the package under test before its integration tests, but
/// only those: so this package has `test_sdid` and `test_sdictl`
/// (src/bin/), thin shells over the same library entry points as
/// `daemon/src/main.rs` and `cli/src/main.rs` (`sdi_daemon::startup::run`,
/// `sdi_cli::run`). They need their own names (two bins called `sdid` in
/// one workspace collide in target/). Activation files and unit sandboxes
/// name the program `sdid`, so each test gets a hard link (or a copy) with
/// the real name in `target/<profile>/sdi-tests-bin/`. The library entry
/// itself runs in the test process in `tests/tests/integration/daemon_in_process.rs`.
///
/// Inside a VM guest (read-only root, no cargo) the programs are the ones
/// the host built and named in `SDID` and `SDICTL` ([`export_bins`]).
pub fn bin(name: &str) -> PathBuf {
    assert!(PROGRAMS.contains(&name), "no test program {name}");
    if let Some(path) = std::env::var_os(name.to_uppercase()) {
        return path.into();
    }
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    // Both at once: `make install` in a test takes the directory of one and
    // installs both.
    DIR.get_or_init(|| {
        let dir = target_dir().join("sdi-tests-bin");
        std::fs::create_dir_all(&dir).expect("create target/<profile>/sdi-tests-bin");
        for program in PROGRAMS {
            link_program(program, &dir);
        }
        // sdid starts the PipeWire camera from beside itself, when it was built.
        if let Some(camera) = crate::pipewire::camera_program() {
            link_file(
                &camera,
                &dir.join(sdi_daemon::sink::pipewire::CAMERA_PROGRAM),
            );
        }
        dir
    })
    .join(name)
}

/// Host side of a test that runs in a VM guest or as another user: names
/// the programs in `SDID` and `SDICTL` for [`bin`] there.
pub fn export_bins() {
    for program in PROGRAMS {
        std::env::set_var(program.to_uppercase(), bin(program));
    }
}

/// The programs [`bin`] provides.
const PROGRAMS: [&str; 2] = ["sdid", "sdictl"];

/// Links the bin `test_<name>` as `dir/<name>`.
fn link_program(name: &str, dir: &Path) {
    let built = format!("test_{name}");
    let source = std::env::var_os(format!("CARGO_BIN_EXE_{built}"))
        .map(PathBuf::from)
        .unwrap_or_else(|| target_dir().join(&built));
    assert!(
        source.is_file(),
        "{} is missing: run the tests through `cargo test -p sdi-tests`, which builds it",
        source.display()
    );
    link_file(&source, &dir.join(name));
}

/// Hard-links (or copies) `source` as `dest`.
fn link_file(source: &Path, dest: &Path) {
    let dir = dest.parent().expect("a file in a directory");
    let name = dest.file_name().expect("a file name").to_string_lossy();
    // A link to a fresh temporary name renamed over the old one: parallel
    // tests never see a half-written program.
    let tmp = dir.join(format!(".{name}.{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    if std::fs::hard_link(source, &tmp).is_err() {
        std::fs::copy(source, &tmp).expect("copy the test program");
    }
    std::fs::rename(&tmp, dest).expect("name the test program");
    // rename(2) does nothing when both names are links to one file.
    let _ = std::fs::remove_file(&tmp);
}

/// True when `dbus-daemon` is installed.
pub fn have_dbus() -> bool {
    Command::new("dbus-daemon")
        .arg("--version")
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A private session bus, killed on drop.
pub struct Bus {
    _child: Reaped,
    pub address: String,
}

impl Bus {
    pub fn start() -> Self {
        Self::start_with(&[])
    }

    /// Like [`Bus::start`] with extra dbus-daemon arguments (e.g.
    /// `--address=unix:abstract=NAME`, a socket no mount namespace hides).
    pub fn start_with(extra: &[&str]) -> Self {
        Self::spawn(&["--session", "--nopidfile"], extra)
    }

    /// A bus with its own configuration file (a system-like policy, a
    /// socket any user may reach).
    pub fn start_config(config: &Path) -> Self {
        Self::spawn(&[&format!("--config-file={}", config.display())], &[])
    }

    /// A bus in `dir` (`bus.conf`, `bus.sock`) any user may connect to and
    /// call anything on: for tests where another uid attacks a root sdid.
    pub fn start_open(dir: &Path) -> Self {
        let config = dir.join("bus.conf");
        std::fs::write(
            &config,
            format!(
                r#"<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-Bus Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>session</type>
  <auth>EXTERNAL</auth>
  <listen>unix:path={}</listen>
  <policy context="default">
    <allow user="*"/>
    <allow own="*"/>
    <allow send_destination="*"/>
    <allow receive_sender="*"/>
  </policy>
</busconfig>
"#,
                dir.join("bus.sock").display()
            ),
        )
        .expect("write bus.conf");
        Self::start_config(&config)
    }

    /// The process id of this bus's dbus-daemon.
    pub fn pid(&self) -> u32 {
        self._child.0.id()
    }

    /// A client connection to this bus.
    pub async fn connect(&self) -> zbus::Connection {
        connect(&self.address).await
    }

    fn spawn(kind: &[&str], extra: &[&str]) -> Self {
        let mut child = Command::new("dbus-daemon")
            .args(kind)
            .args(["--nofork", "--print-address=1"])
            .args(extra)
            .stdout(Stdio::piped())
            .spawn()
            .expect("start dbus-daemon");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("read bus address");
        let address = line.trim().to_owned();
        assert!(!address.is_empty(), "dbus-daemon printed no address");
        Self {
            _child: Reaped(child),
            address,
        }
    }
}

/// Longest a test's D-Bus call may wait for its reply: far beyond any
/// call the tests make (their jobs take seconds), so a daemon that stopped
/// answering fails the test with an error instead of hanging the run.
pub const METHOD_TIMEOUT: Duration = Duration::from_secs(180);

/// A client connection to the bus at `address` (calls time out after
/// [`METHOD_TIMEOUT`]).
pub async fn connect(address: &str) -> zbus::Connection {
    zbus::connection::Builder::address(address)
        .expect("bus address")
        .method_timeout(METHOD_TIMEOUT)
        .build()
        .await
        .expect("connect to the bus")
}

/// A connection to `address` and an untyped proxy of sdid's camera object,
/// for calls the typed `sdi_api` proxy cannot make (wrong arguments, raw
/// error names).
pub async fn raw_camera_proxy(address: &str) -> (zbus::Connection, zbus::Proxy<'static>) {
    let conn = connect(address).await;
    let proxy = zbus::Proxy::new(
        &conn,
        "org.sdi.Daemon",
        "/org/sdi/Camera0",
        "org.sdi.Camera1",
    )
    .await
    .expect("camera proxy");
    (conn, proxy)
}

/// A running `sdid` on a [`Bus`], killed on drop.
pub struct Daemon {
    pub child: Child,
    pub address: String,
}

impl Daemon {
    /// Starts `sdid --bus-address ADDR --backend sim --sink y4m` (stdout to /dev/null)
    /// plus `extra` arguments, and waits until it answers.
    pub fn start(bus: &Bus, extra: &[&str]) -> Self {
        Self::start_wrapped(bus, &[], extra)
    }

    /// [`Daemon::start`] on a new [`Bus`]; bind both, the bus first, so
    /// that sdid is stopped before its bus.
    pub fn start_on_new_bus(extra: &[&str]) -> (Bus, Self) {
        let bus = Bus::start();
        let daemon = Self::start(&bus, extra);
        (bus, daemon)
    }

    /// Like [`Daemon::start`], with sdid run by `wrapper` (a program and its
    /// arguments, which must exec sdid in the same process, e.g. `unshare`).
    pub fn start_wrapped(bus: &Bus, wrapper: &[&str], extra: &[&str]) -> Self {
        let d = Self::spawn(
            bus,
            Self::command(bus, wrapper, extra)
                .stdout(Stdio::null())
                .stderr(Stdio::inherit()),
        );
        d.wait_ready();
        d
    }

    /// Spawns `cmd` (an sdid for `bus`, e.g. from [`Daemon::command`]) and
    /// returns at once; [`Daemon::wait_ready`] waits until it answers.
    pub fn spawn(bus: &Bus, cmd: &mut Command) -> Self {
        Self {
            child: cmd.spawn().expect("start sdid"),
            address: bus.address.clone(),
        }
    }

    /// The command [`Daemon::start_wrapped`] runs, for a test that needs to
    /// spawn it itself (e.g. with stderr piped).
    pub fn command(bus: &Bus, wrapper: &[&str], extra: &[&str]) -> Command {
        let mut cmd = Self::bare_command(bus, wrapper);
        cmd.args(["--sink", "y4m", "--y4m-path", "-"])
            .args(["--frame-rate-hz", "30", "--exposure-us", "2000"])
            .args(extra);
        cmd
    }

    /// sdid for `bus` (run by `wrapper`, if any) with only the bus address
    /// and the environment of a test: no sink, rate or exposure.
    pub fn bare_command(bus: &Bus, wrapper: &[&str]) -> Command {
        SdidCommand::wrapped_by(wrapper).bus(&bus.address).command()
    }

    /// Waits until sdid answers on its bus.
    pub fn wait_ready(&self) {
        wait_until(
            &format!("sdid on {}", self.address),
            Duration::from_secs(30),
            || self.ctl(&["get", "mode"]).status.success(),
        );
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Runs `sdictl --bus-address ADDR args...`.
    pub fn ctl(&self, args: &[&str]) -> Output {
        sdictl(&self.address, args)
    }

    /// Sends a signal and waits for the exit status.
    pub fn signal(&mut self, sig: Signal) -> std::process::ExitStatus {
        crate::process::signal(self.child.id(), sig);
        wait_for("sdid to exit", Duration::from_secs(20), || {
            self.child.try_wait().expect("wait sdid")
        })
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs the built `sdictl` against the bus at `address`, killed after
/// [`METHOD_TIMEOUT`] (exit 124) so that a daemon that stopped answering
/// fails the test instead of hanging the run.
pub fn sdictl(address: &str, args: &[&str]) -> Output {
    Command::new("timeout")
        .args(["-k", "5", &METHOD_TIMEOUT.as_secs().to_string()])
        .arg(bin("sdictl"))
        .args(["--bus-address", address])
        .args(args)
        .output()
        .expect("run sdictl")
}

/// [`sdictl`] that must succeed (its stderr in the panic); its stdout,
/// trimmed.
pub fn sdictl_ok(address: &str, args: &[&str]) -> String {
    let out = sdictl(address, args);
    assert!(
        out.status.success(),
        "sdictl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).trim().to_owned()
}

/// Reads the daemon's Stats property as JSON.
pub fn stats(d: &Daemon) -> serde_json::Value {
    let out = d.ctl(&["--json", "get", "stats"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    v["Stats"].clone()
}

/// Skips (with a message) when dbus-daemon is missing.
#[macro_export]
macro_rules! require_dbus {
    () => {
        if !$crate::dbus::have_dbus() {
            $crate::skipped!("SKIPPED: dbus-daemon is not installed (apt-get install dbus)");
            return;
        }
    };
}

/// Sends `calls` SetMode calls (cycling through four modes) on `conn`
/// without waiting for the replies: the flood of the fair-share tests.
pub async fn send_set_mode_flood(conn: &zbus::Connection, calls: usize) {
    let modes = ["depth-edge", "raw", "bipolar-colour", "two-shot"];
    for i in 0..calls {
        let msg = zbus::Message::method_call("/org/sdi/Camera0", "SetMode")
            .expect("SetMode call")
            .destination("org.sdi.Daemon")
            .expect("destination")
            .interface("org.sdi.Camera1")
            .expect("interface")
            .build(&(modes[i % modes.len()],))
            .expect("SetMode body");
        conn.send(&msg).await.expect("send SetMode");
    }
}

/// Records `seconds` of the simulator into `rec` with a daemon of its own
/// on a bus of its own (a recording to replay), and stops both.
pub fn record_sim(rec: &Path, seconds: f64) {
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let out = d.ctl(&[
        "record",
        &rec.to_string_lossy(),
        "--seconds",
        &seconds.to_string(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A current-thread tokio runtime for a test's D-Bus calls.
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("tokio runtime")
}

/// Calls `attempt` every 20 ms until it succeeds; its value and how long
/// that took, or its last error once `within` has passed.
pub async fn until_ok<T, E, F, Fut>(
    within: Duration,
    mut attempt: F,
) -> Result<(T, Duration), String>
where
    E: std::fmt::Display,
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Result<T, E>>,
{
    let t0 = std::time::Instant::now();
    loop {
        match attempt().await {
            Ok(v) => return Ok((v, t0.elapsed())),
            Err(e) if t0.elapsed() > within => {
                return Err(format!("still refused after {:?}: {e}", t0.elapsed()))
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
        }
    }
}

/// The FIFO `path`, made and opened read-write: a descriptor whose reading
/// side its holder has too.
pub fn read_write_fifo(path: &Path) -> std::fs::File {
    nix::unistd::mkfifo(path, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .expect("open the FIFO read-write")
}
