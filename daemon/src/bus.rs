//! Which bus to serve on, including a private session bus when none exists.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

pub use sdi_api::bus::{private_bus_file, session_address};

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
