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

/// True when `program --version` (or `args`) runs here. Otherwise prints
/// the skip line naming the Debian `package` and returns false; with
/// `SDI_REQUIRE_VM` set (CI installs every package) that is a failure.
pub fn have(program: &str, args: &[&str], package: &str, what: &str) -> bool {
    let runs = std::process::Command::new(program)
        .args(if args.is_empty() {
            &["--version"]
        } else {
            args
        })
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !runs {
        assert!(
            std::env::var_os("SDI_REQUIRE_VM").is_none(),
            "{what} needs {program} and SDI_REQUIRE_VM is set (apt-get install {package})"
        );
        line(format_args!(
            "SKIPPED: {what} needs {program} (apt-get install {package})"
        ));
    }
    runs
}
