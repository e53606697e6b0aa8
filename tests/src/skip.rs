//! The one line a test prints when it skips for a missing system part.
//!
//! Written to the stderr handle, not with `eprintln!`: libtest captures what
//! the print macros of a passing test write, so a skip would never be seen
//! in `cargo test`'s output.

use std::fmt;
use std::io::Write;

/// Writes `line` to stderr past libtest's capture.
pub fn line(line: fmt::Arguments<'_>) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// `skipped!("SKIPPED: ... (apt-get install PACKAGE)")`: [`line`] with
/// `format!` arguments.
#[macro_export]
macro_rules! skipped {
    ($($arg:tt)*) => {
        $crate::skip::line(format_args!($($arg)*))
    };
}
