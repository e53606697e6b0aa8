//! Which bus to serve on, including a private session bus when none exists.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

/// Where `sdid --session` writes the address of a private bus it started,
/// so `sdictl --session` finds it.
pub fn private_bus_file() -> PathBuf {
    let dir = std::env::var_os("XDG_RUNTIME_DIR")
        .map(PathBuf::from)
        .filter(|d| d.is_dir())
        .unwrap_or_else(|| PathBuf::from("/tmp"));
    dir.join(format!("sdid-session-bus-{}", nix::unistd::getuid()))
}

/// The session bus address from the environment or `$XDG_RUNTIME_DIR/bus`.
pub fn session_address() -> Option<String> {
    if let Some(a) = std::env::var("DBUS_SESSION_BUS_ADDRESS")
        .ok()
        .filter(|a| !a.is_empty())
    {
        return Some(a);
    }
    let rt = std::env::var_os("XDG_RUNTIME_DIR")?;
    let sock = PathBuf::from(rt).join("bus");
    sock.exists()
        .then(|| format!("unix:path={}", sock.display()))
}

/// A `dbus-daemon --session` this process started; killed on drop.
pub struct PrivateBus {
    child: Child,
    pub address: String,
}

impl PrivateBus {
    pub fn spawn() -> std::io::Result<Self> {
        let mut child = Command::new("dbus-daemon")
            .args(["--session", "--nofork", "--nopidfile", "--print-address=1"])
            .stdout(Stdio::piped())
            .stdin(Stdio::null())
            .spawn()?;
        let mut line = String::new();
        if let Some(out) = child.stdout.take() {
            BufReader::new(out).read_line(&mut line)?;
        }
        let address = line.trim().to_owned();
        if address.is_empty() {
            let _ = child.kill();
            return Err(std::io::Error::other("dbus-daemon printed no address"));
        }
        let _ = std::fs::write(private_bus_file(), format!("{address}\n"));
        Ok(Self { child, address })
    }
}

impl Drop for PrivateBus {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(private_bus_file());
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
