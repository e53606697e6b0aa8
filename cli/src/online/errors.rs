//! Errors of the online subcommands and their exit statuses.
//!
//! | status | meaning |
//! | --- | --- |
//! | 0 | success |
//! | 1 | failed (I/O, unexpected D-Bus error) |
//! | 2 | invalid input: unknown mode or property, out of range, bad path (also clap's usage errors) |
//! | 3 | daemon not reachable (no bus, `org.sdi.Daemon` not running, timeout) |
//! | 4 | busy (another dark-frame/calibration/recording) |
//! | 5 | device unavailable |
//! | 6 | nothing to do: not recording, no frame yet |
//!
//! A closed stdout (the reader went away) ends a command quietly with 0
//! (`stdout.rs`).

use std::io::Write;
use std::process::ExitCode;

#[derive(Debug, thiserror::Error)]
pub enum OnlineError {
    #[error("{0}")]
    Invalid(String),
    #[error("{0}")]
    Unreachable(String),
    #[error("{0}")]
    Busy(String),
    #[error("{0}")]
    Device(String),
    #[error("{0}")]
    Nothing(String),
    #[error("{0}")]
    Failed(String),
    /// The reader of stdout went away: stop quietly, exit status 0.
    #[error("stdout is closed")]
    StdoutClosed,
}

impl From<crate::stdout::StdoutError> for OnlineError {
    fn from(e: crate::stdout::StdoutError) -> Self {
        match e {
            crate::stdout::StdoutError::Closed => OnlineError::StdoutClosed,
            crate::stdout::StdoutError::Failed(_) => OnlineError::Failed(e.to_string()),
        }
    }
}

impl OnlineError {
    pub fn exit_code(&self) -> u8 {
        match self {
            OnlineError::Failed(_) => 1,
            OnlineError::Invalid(_) => 2,
            OnlineError::Unreachable(_) => 3,
            OnlineError::Busy(_) => 4,
            OnlineError::Device(_) => 5,
            OnlineError::Nothing(_) => 6,
            OnlineError::StdoutClosed => 0,
        }
    }

    /// The D-Bus error name, for `--json` output.
    pub fn kind(&self) -> &'static str {
        match self {
            OnlineError::Failed(_) => "failed",
            OnlineError::Invalid(_) => "invalid",
            OnlineError::Unreachable(_) => "unreachable",
            OnlineError::Busy(_) => "busy",
            OnlineError::Device(_) => "device-unavailable",
            OnlineError::Nothing(_) => "nothing-to-do",
            OnlineError::StdoutClosed => "stdout-closed",
        }
    }
}

/// The daemon's own errors, by variant (the contract in `sdi_api`).
impl From<sdi_api::SdiError> for OnlineError {
    fn from(e: sdi_api::SdiError) -> Self {
        use sdi_api::SdiError as E;
        let name = zbus::DBusError::name(&e).to_string();
        let text = |m: String| format!("{name}: {m}");
        match e {
            E::ZBus(z) => OnlineError::from(z),
            E::InvalidMode(m) | E::OutOfRange(m) | E::InvalidPath(m) | E::InvalidFd(m) => {
                OnlineError::Invalid(text(m))
            }
            E::Busy(m) => OnlineError::Busy(text(m)),
            E::DeviceUnavailable(m) => OnlineError::Device(text(m)),
            E::NotRecording(m) | E::NoFrame(m) => OnlineError::Nothing(text(m)),
            E::Failed(m) | E::RecordingStopped(m) => OnlineError::Failed(text(m)),
        }
    }
}

/// Transport and standard D-Bus errors.
impl From<zbus::Error> for OnlineError {
    fn from(e: zbus::Error) -> Self {
        match &e {
            zbus::Error::MethodError(name, msg, _) => {
                let msg = format!("{}: {}", name.as_str(), msg.as_deref().unwrap_or(""));
                match name.as_str() {
                    "org.freedesktop.DBus.Error.InvalidArgs"
                    | "org.freedesktop.DBus.Error.UnknownProperty" => OnlineError::Invalid(msg),
                    "org.freedesktop.DBus.Error.AccessDenied" => OnlineError::Failed(format!(
                        "{msg} (only members of the group sdi may control the camera: sudo usermod -aG sdi $USER, then log in again)"
                    )),
                    "org.freedesktop.DBus.Error.ServiceUnknown"
                    | "org.freedesktop.DBus.Error.NameHasNoOwner"
                    | "org.freedesktop.DBus.Error.NoReply"
                    | "org.freedesktop.DBus.Error.Timeout" => OnlineError::Unreachable(format!(
                        "{msg} (is sdid running? start it with `sdid --session` or `systemctl start sdid`)"
                    )),
                    _ => OnlineError::Failed(msg),
                }
            }
            zbus::Error::FDO(f) => match **f {
                zbus::fdo::Error::ServiceUnknown(_)
                | zbus::fdo::Error::NameHasNoOwner(_)
                | zbus::fdo::Error::NoReply(_)
                | zbus::fdo::Error::Timeout(_) => OnlineError::Unreachable(format!(
                    "{e} (is sdid running? start it with `sdid --session` or `systemctl start sdid`)"
                )),
                zbus::fdo::Error::InvalidArgs(_) | zbus::fdo::Error::UnknownProperty(_) => {
                    OnlineError::Invalid(e.to_string())
                }
                _ => OnlineError::Failed(e.to_string()),
            },
            zbus::Error::InputOutput(_) | zbus::Error::Address(_) | zbus::Error::Handshake(_) => {
                OnlineError::Unreachable(format!("cannot reach the bus: {e}"))
            }
            _ => OnlineError::Failed(e.to_string()),
        }
    }
}

/// Prints the error (as JSON when asked) and maps it to the exit status.
pub fn report(result: Result<(), OnlineError>, json: bool) -> ExitCode {
    match result {
        Ok(()) | Err(OnlineError::StdoutClosed) => ExitCode::SUCCESS,
        Err(e) => {
            // Already failing: a stdout or stderr that cannot take the
            // message changes nothing (and must not panic).
            if json {
                let _ = crate::stdout::outln!(
                    "{}",
                    serde_json::json!({"error": e.kind(), "message": e.to_string()})
                );
            }
            let _ = writeln!(std::io::stderr(), "error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
