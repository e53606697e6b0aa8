//! Errors of a subcommand and the exit status each maps to.

use std::io::Write;
use std::process::ExitCode;

use crate::stdout::StdoutError;

/// What went wrong, and whose fault it is.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// Bad input from the user (unknown name, value out of range): exit status 2,
    /// the same as clap's own parse errors.
    #[error("{0}")]
    Usage(String),
    /// The command was valid but could not be carried out (I/O...): exit status 1.
    #[error("{0}")]
    Runtime(String),
    /// The reader of stdout went away: the command stops quietly, exit status 0
    /// (`stdout.rs`).
    #[error("stdout is closed")]
    StdoutClosed,
}

impl CliError {
    pub fn exit_code(&self) -> u8 {
        match self {
            CliError::Usage(_) => 2,
            CliError::Runtime(_) => 1,
            CliError::StdoutClosed => 0,
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

/// Prints the error, if any, and turns it into the process exit status.
pub fn report(result: Result<(), CliError>) -> ExitCode {
    match result {
        Ok(()) | Err(CliError::StdoutClosed) => ExitCode::SUCCESS,
        Err(e) => {
            // Not eprintln!: a closed or full stderr must not panic either.
            let _ = writeln!(std::io::stderr(), "error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
