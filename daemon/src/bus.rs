//! Which bus to serve on, including a private session bus when none exists.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

pub use sdi_api::bus::{private_bus_file, session_address};

/// A `dbus-daemon --session` this process started; killed on drop, and by
/// the kernel when sdid dies any other way (kill -9, a crash): it runs under
/// `setpriv --pdeathsig KILL` (util-linux), which sets PR_SET_PDEATHSIG and
/// execs it, so no `unsafe` pre-exec hook is needed here.
pub struct PrivateBus {
    child: Child,
    pub address: String,
}

impl PrivateBus {
    pub fn spawn() -> std::io::Result<Self> {
        const DBUS: [&str; 5] = [
            "dbus-daemon",
            "--session",
            "--nofork",
            "--nopidfile",
            "--print-address=1",
        ];
        // Its stderr comes through our log, a line at a time: written
        // straight to ours, its start-up warnings could land in the middle
        // of the address announcement below and garble the address.
        let spawn = |program: &str, args: &[&str]| {
            Command::new(program)
                .args(args)
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .stdin(Stdio::null())
                .spawn()
        };
        let mut with_pdeathsig = vec!["--pdeathsig", "KILL", "--"];
        with_pdeathsig.extend(DBUS);
        let mut child = match spawn("setpriv", &with_pdeathsig) {
            Ok(c) => c,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                tracing::warn!(
                    "setpriv (util-linux) not found: the private bus outlives sdid if it is killed"
                );
                spawn(DBUS[0], &DBUS[1..])?
            }
            Err(e) => return Err(e),
        };
        if let Some(err) = child.stderr.take() {
            std::thread::Builder::new()
                .name("sdid-bus-log".into())
                .spawn(move || {
                    for line in BufReader::new(err).lines().map_while(Result::ok) {
                        tracing::debug!(target: "sdid::private_bus", "{line}");
                    }
                })?;
        }
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

/// The bus sdid serves on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BusChoice {
    /// The system bus (the installed service).
    System,
    /// The session bus; a private one is started when none exists.
    Session,
    /// The bus at this address.
    Address(String),
}

/// Why the chosen bus could not be reached.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    #[error("no session bus and cannot start dbus-daemon: {0} (install dbus)")]
    NoDbusDaemon(#[source] std::io::Error),
    #[error("{0}")]
    Address(#[source] zbus::Error),
    #[error("connecting to D-Bus: {0}")]
    Connect(#[source] zbus::Error),
}

/// Connects to the chosen bus; the private bus started for
/// [`BusChoice::Session`], if any, lives as long as the returned handle.
pub async fn connect(
    choice: &BusChoice,
) -> Result<(zbus::Connection, Option<PrivateBus>), ConnectError> {
    let mut private = None;
    let builder = match choice {
        BusChoice::Address(a) => zbus::connection::Builder::address(a.as_str()),
        BusChoice::Session => {
            let addr = match session_address() {
                Some(a) => a,
                None => {
                    let p = PrivateBus::spawn().map_err(ConnectError::NoDbusDaemon)?;
                    // One write: the announcement stays whole beside
                    // other writers of the same stderr.
                    let announcement = format!(
                        "sdid: no session bus found; started a private one:\n  export DBUS_SESSION_BUS_ADDRESS='{}'\n(sdictl --session finds it automatically)\n",
                        p.address
                    );
                    let _ = std::io::Write::write_all(
                        &mut std::io::stderr().lock(),
                        announcement.as_bytes(),
                    );
                    let a = p.address.clone();
                    private = Some(p);
                    a
                }
            };
            zbus::connection::Builder::address(addr.as_str())
        }
        BusChoice::System => zbus::connection::Builder::system(),
    }
    .map_err(ConnectError::Address)?;
    let conn = builder.build().await.map_err(ConnectError::Connect)?;
    Ok((conn, private))
}
