//! Helpers for D-Bus integration tests: a private `dbus-daemon` per test,
//! the built `sdid` on it, and `sdictl` pointed at it.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// `target/<profile>` of the running test binary.
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test exe path");
    // target/<profile>/deps/<test>-<hash>
    exe.parent()
        .and_then(Path::parent)
        .expect("target dir")
        .to_owned()
}

/// Path of a workspace binary, built once per test process (cargo is a no-op when fresh).
pub fn bin(name: &str) -> PathBuf {
    static BUILT: OnceLock<()> = OnceLock::new();
    BUILT.get_or_init(|| {
        let dir = target_dir();
        let release = dir.file_name().is_some_and(|n| n == "release");
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args(["build", "-q", "-p", "sdi-daemon", "-p", "sdi-cli", "--bins"]);
        // Same profile as `cargo test` (opt-level 2), so its binaries are reused.
        cmd.args(["--profile", if release { "release" } else { "test" }]);
        if let Some(root) = dir.parent() {
            cmd.env("CARGO_TARGET_DIR", root);
        }
        let status = cmd.status().expect("run cargo build");
        assert!(status.success(), "building sdid/sdictl failed");
    });
    target_dir().join(name)
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
    child: Child,
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
        Self { child, address }
    }
}

impl Drop for Bus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A connection to `address` and an untyped proxy of sdid's camera object,
/// for calls the typed `sdi_api` proxy cannot make (wrong arguments, raw
/// error names).
pub async fn raw_camera_proxy(address: &str) -> (zbus::Connection, zbus::Proxy<'static>) {
    let conn = zbus::connection::Builder::address(address)
        .expect("bus address")
        .build()
        .await
        .expect("connect to the bus");
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

    /// Like [`Daemon::start`], with sdid run by `wrapper` (a program and its
    /// arguments, which must exec sdid in the same process, e.g. `unshare`).
    pub fn start_wrapped(bus: &Bus, wrapper: &[&str], extra: &[&str]) -> Self {
        let child = Self::command(bus, wrapper, extra)
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start sdid");
        let d = Self {
            child,
            address: bus.address.clone(),
        };
        d.wait_ready();
        d
    }

    /// The command [`Daemon::start_wrapped`] runs, for a test that needs to
    /// spawn it itself (e.g. with stderr piped).
    pub fn command(bus: &Bus, wrapper: &[&str], extra: &[&str]) -> Command {
        let mut cmd = match wrapper.split_first() {
            Some((program, args)) => {
                let mut c = Command::new(program);
                c.args(args).arg(bin("sdid"));
                c
            }
            None => Command::new(bin("sdid")),
        };
        cmd.args([
            "--bus-address",
            &bus.address,
            "--sink",
            "y4m",
            "--y4m-path",
            "-",
        ])
        .args(["--frame-rate-hz", "30", "--exposure-us", "2000"])
        .args(extra)
        .env("RUST_LOG", "warn")
        // Not a systemd service, even when the tests run inside one.
        .env_remove("INVOCATION_ID");
        cmd
    }

    fn wait_ready(&self) {
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(30) {
            if self.ctl(&["get", "mode"]).status.success() {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!("sdid did not come up on {}", self.address);
    }

    /// Runs `sdictl --bus-address ADDR args...`.
    pub fn ctl(&self, args: &[&str]) -> Output {
        sdictl(&self.address, args)
    }

    /// Sends a signal and waits for the exit status.
    pub fn signal(&mut self, sig: i32) -> std::process::ExitStatus {
        // SAFETY: plain kill(2) on our own child's pid.
        unsafe {
            libc::kill(self.child.id() as i32, sig);
        }
        let start = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().expect("wait sdid") {
                return s;
            }
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "sdid did not exit"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs the built `sdictl` against the bus at `address`.
pub fn sdictl(address: &str, args: &[&str]) -> Output {
    Command::new(bin("sdictl"))
        .args(["--bus-address", address])
        .args(args)
        .output()
        .expect("run sdictl")
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
            eprintln!("SKIPPED: dbus-daemon is not installed (apt-get install dbus)");
            return;
        }
    };
}
