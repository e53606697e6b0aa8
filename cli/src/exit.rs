//! sdictl's one error type and the exit status each error maps to.
//!
//! | status | meaning |
//! | --- | --- |
//! | 0 | success; also a closed stdout (the reader went away, `stdout.rs`) |
//! | 1 | failed (I/O, unexpected D-Bus error, access denied) |
//! | 2 | invalid input: unknown mode or property, out of range, bad path (also clap's usage errors) |
//! | 3 | daemon not reachable (no bus, `org.sdi.Daemon` not running, timeout) |
//! | 4 | busy (another dark-frame/calibration/recording) |
//! | 5 | device unavailable |
//! | 6 | nothing to do: not recording, no frame yet |

use std::io::Write;
use std::process::ExitCode;

use sdi_api::{SdiError, SettingError};

use crate::stdout::StdoutError;

/// What went wrong; [`CliError::outcome`] says which row of the table it is.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// Bad input from the user (unknown name, value out of range, a path
    /// that cannot be used).
    #[error("{0}")]
    Usage(String),
    /// The command was valid but could not be carried out (I/O...).
    #[error("{0}")]
    Runtime(String),
    /// A setting's name or value that sdictl refuses before asking sdid.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// One of sdid's own errors (`org.sdi.Error.*`).
    /// Shown as zbus's `DBusError` derive shows it: "NAME: message".
    #[error(transparent)]
    Daemon(SdiError),
    /// A transport or standard D-Bus error.
    #[error("{}", bus_message(.0))]
    Bus(zbus::Error),
    /// No bus to connect to, or none within the time allowed.
    #[error("{0}")]
    Unreachable(String),
    /// The bus refused the connection.
    #[error("cannot connect to the bus: {0}")]
    Connect(#[source] zbus::Error),
    /// A reply that does not encode as its D-Bus dictionary.
    #[error("encoding a reply as JSON: {0}")]
    Encode(#[source] zbus::zvariant::Error),
    /// The reader of stdout went away: the command stops quietly.
    #[error("stdout is closed")]
    StdoutClosed,
}

/// A row of the exit-status table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Quiet,
    Failed,
    Invalid,
    Unreachable,
    Busy,
    DeviceUnavailable,
    NothingToDo,
}

impl Outcome {
    pub fn exit_code(self) -> u8 {
        match self {
            Outcome::Quiet => 0,
            Outcome::Failed => 1,
            Outcome::Invalid => 2,
            Outcome::Unreachable => 3,
            Outcome::Busy => 4,
            Outcome::DeviceUnavailable => 5,
            Outcome::NothingToDo => 6,
        }
    }

    /// The name `--json` prints as `error`.
    pub fn kind(self) -> &'static str {
        match self {
            Outcome::Quiet => "stdout-closed",
            Outcome::Failed => "failed",
            Outcome::Invalid => "invalid",
            Outcome::Unreachable => "unreachable",
            Outcome::Busy => "busy",
            Outcome::DeviceUnavailable => "device-unavailable",
            Outcome::NothingToDo => "nothing-to-do",
        }
    }
}

impl CliError {
    pub fn outcome(&self) -> Outcome {
        match self {
            CliError::Usage(_) | CliError::Setting(_) => Outcome::Invalid,
            CliError::Runtime(_) | CliError::Encode(_) => Outcome::Failed,
            CliError::Daemon(e) => daemon_outcome(e),
            CliError::Bus(e) => bus_outcome(e),
            CliError::Unreachable(_) | CliError::Connect(_) => Outcome::Unreachable,
            CliError::StdoutClosed => Outcome::Quiet,
        }
    }
}

impl From<StdoutError> for CliError {
    fn from(e: StdoutError) -> Self {
        match e {
            StdoutError::Closed => CliError::StdoutClosed,
            StdoutError::Failed(_) => CliError::Runtime(e.to_string()),
        }
    }
}

/// sdid's errors by variant; a transport error inside is a bus error.
impl From<SdiError> for CliError {
    fn from(e: SdiError) -> Self {
        match e {
            SdiError::ZBus(z) => CliError::Bus(z),
            e => CliError::Daemon(e),
        }
    }
}

impl From<zbus::Error> for CliError {
    fn from(e: zbus::Error) -> Self {
        CliError::Bus(e)
    }
}

fn daemon_outcome(e: &SdiError) -> Outcome {
    match e {
        SdiError::ZBus(z) => bus_outcome(z),
        SdiError::InvalidMode(_)
        | SdiError::OutOfRange(_)
        | SdiError::InvalidPath(_)
        | SdiError::InvalidFd(_) => Outcome::Invalid,
        SdiError::Busy(_) => Outcome::Busy,
        SdiError::DeviceUnavailable(_) => Outcome::DeviceUnavailable,
        SdiError::NotRecording(_) | SdiError::NoFrame(_) => Outcome::NothingToDo,
        SdiError::Failed(_) | SdiError::RecordingStopped(_) | SdiError::Cancelled(_) => {
            Outcome::Failed
        }
    }
}

/// What a standard D-Bus error means for sdictl, by its name.
fn error_name_outcome(name: &str) -> Outcome {
    match name {
        "org.freedesktop.DBus.Error.InvalidArgs" | "org.freedesktop.DBus.Error.UnknownProperty" => {
            Outcome::Invalid
        }
        "org.freedesktop.DBus.Error.ServiceUnknown"
        | "org.freedesktop.DBus.Error.NameHasNoOwner"
        | "org.freedesktop.DBus.Error.NoReply"
        | "org.freedesktop.DBus.Error.Timeout" => Outcome::Unreachable,
        _ => Outcome::Failed,
    }
}

fn bus_outcome(e: &zbus::Error) -> Outcome {
    match e {
        zbus::Error::MethodError(name, _, _) => error_name_outcome(name.as_str()),
        zbus::Error::FDO(f) => error_name_outcome(zbus::DBusError::name(&**f).as_str()),
        zbus::Error::InputOutput(_) | zbus::Error::Address(_) | zbus::Error::Handshake(_) => {
            Outcome::Unreachable
        }
        _ => Outcome::Failed,
    }
}

const START_SDID: &str =
    "(is sdid running? start it with `sdid --session` or `systemctl start sdid`)";
const JOIN_SDI: &str = "(only members of the group sdi may control the camera: sudo usermod -aG sdi $USER, then log in again)";

/// The error as the user reads it, with what to do where sdictl knows.
fn bus_message(e: &zbus::Error) -> String {
    let (text, name) = match e {
        zbus::Error::MethodError(name, msg, _) => (
            format!("{}: {}", name.as_str(), msg.as_deref().unwrap_or("")),
            name.to_string(),
        ),
        zbus::Error::FDO(f) => (e.to_string(), zbus::DBusError::name(&**f).to_string()),
        zbus::Error::InputOutput(_) | zbus::Error::Address(_) | zbus::Error::Handshake(_) => {
            return format!("cannot reach the bus: {e}")
        }
        _ => return e.to_string(),
    };
    match (bus_outcome(e), name.as_str()) {
        (Outcome::Unreachable, _) => format!("{text} {START_SDID}"),
        (_, "org.freedesktop.DBus.Error.AccessDenied") => format!("{text} {JOIN_SDI}"),
        _ => text,
    }
}

/// Prints the error, if any (also as JSON on stdout when `json`), and turns
/// the outcome into the process exit status.
pub fn report(result: Result<(), CliError>, json: bool) -> ExitCode {
    let e = match result {
        Ok(()) => return ExitCode::SUCCESS,
        Err(e) => e,
    };
    let outcome = e.outcome();
    if outcome == Outcome::Quiet {
        return ExitCode::SUCCESS;
    }
    // Already failing: a stdout or stderr that cannot take the message
    // changes nothing (and must not panic; hence not eprintln!).
    if json {
        let _ = crate::stdout::outln!(
            "{}",
            serde_json::json!({"error": outcome.kind(), "message": e.to_string()})
        );
    }
    let _ = writeln!(std::io::stderr(), "error: {e}");
    ExitCode::from(outcome.exit_code())
}

/// Prints the JSON error object of a usage error clap found (the text
/// itself goes to stderr as clap prints it).
pub fn report_usage_json(message: &str) {
    let _ = crate::stdout::outln!(
        "{}",
        serde_json::json!({"error": Outcome::Invalid.kind(), "message": message})
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn daemon_errors_keep_their_names_and_statuses() {
        let code = |e: CliError| e.outcome().exit_code();
        let e = CliError::from(SdiError::OutOfRange("allowed (0, 1]".into()));
        assert_eq!(e.to_string(), "org.sdi.Error.OutOfRange: allowed (0, 1]");
        assert_eq!(code(e), 2);
        assert_eq!(code(SdiError::Busy(String::new()).into()), 4);
        assert_eq!(code(SdiError::DeviceUnavailable(String::new()).into()), 5);
        assert_eq!(code(SdiError::NoFrame(String::new()).into()), 6);
        assert_eq!(code(CliError::StdoutClosed), 0);
    }

    #[test]
    fn a_missing_daemon_is_unreachable_and_says_how_to_start_it() {
        let e = CliError::from(zbus::Error::from(zbus::fdo::Error::ServiceUnknown(
            "org.sdi.Daemon".into(),
        )));
        assert_eq!(e.outcome().exit_code(), 3);
        assert!(e.to_string().contains("sdid --session"), "{e}");
    }
}
