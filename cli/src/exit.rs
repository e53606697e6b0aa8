//! Errors of a subcommand and the exit status each maps to.

use std::process::ExitCode;

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
}

impl CliError {
    pub fn exit_code(&self) -> u8 {
        match self {
            CliError::Usage(_) => 2,
            CliError::Runtime(_) => 1,
        }
    }
}

/// Prints the error, if any, and turns it into the process exit status.
pub fn report(result: Result<(), CliError>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
