//! sdictl's standard output. `println!` panics when stdout is closed or full
//! ("failed printing to stdout", exit status 101), so every line goes
//! through [`outln!`] instead and a failure is an error like any other:
//!
//! - the reader went away (EPIPE: `sdictl ... | head -1`, `| true`): the
//!   command ends quietly with exit status 0, as when the rest of the output
//!   is simply not wanted. Files are always written before anything is
//!   printed, so nothing is lost. Rust starts with SIGPIPE ignored, so a
//!   closed pipe arrives here as EPIPE; the shell convention of dying by the
//!   signal (status 141) would need `unsafe` to restore it, for no gain.
//! - any other failure (ENOSPC on `/dev/full`, EIO): "cannot write to
//!   stdout: ..." on stderr and exit status 1.

use std::io::Write;

/// Why a line could not be printed.
#[derive(Debug, thiserror::Error)]
pub enum StdoutError {
    /// The reading end of the pipe is closed (EPIPE).
    #[error("stdout is closed")]
    Closed,
    #[error("cannot write to stdout: {0}")]
    Failed(std::io::Error),
}

impl From<std::io::Error> for StdoutError {
    fn from(e: std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            StdoutError::Closed
        } else {
            StdoutError::Failed(e)
        }
    }
}

/// Writes `bytes` and flushes, so the error (if any) is this call's.
pub fn write_all(bytes: &[u8]) -> Result<(), StdoutError> {
    let mut out = std::io::stdout().lock();
    out.write_all(bytes)?;
    out.flush()?;
    Ok(())
}

/// Writes one formatted line (see [`outln!`]).
pub fn write_line(args: std::fmt::Arguments) -> Result<(), StdoutError> {
    let mut line = args.to_string();
    line.push('\n');
    write_all(line.as_bytes())
}

/// `println!` that returns `Result<(), StdoutError>` instead of panicking.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::stdout::write_line(format_args!($($arg)*))
    };
}
pub(crate) use outln;
