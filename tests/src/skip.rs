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

/// The one place a test reads CI's require flags (`SDI_REQUIRE_VM`,
/// `SDI_REQUIRE_PACKAGING`): a part the test needs is missing, so it fails
/// when `require` is set and otherwise prints `SKIPPED: what`.
pub fn unavailable(require: &str, what: fmt::Arguments<'_>) {
    assert!(
        std::env::var_os(require).is_none(),
        "{what}, and {require} is set"
    );
    line(format_args!("SKIPPED: {what}"));
}

/// True when every program in `tools` (name, Debian package) is on the
/// PATH. Otherwise prints one line naming the missing packages and returns
/// false, or fails when the environment variable `require` is set (CI sets
/// each such flag).
pub fn have_all(what: &str, tools: &[(&str, &str)], require: &str) -> bool {
    let missing: Vec<&str> = tools
        .iter()
        .filter(|(program, _)| {
            !std::process::Command::new("sh")
                .args(["-c", &format!("command -v {program}")])
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .map(|(_, package)| *package)
        .collect();
    if missing.is_empty() {
        return true;
    }
    let text = format!(
        "{what} needs the Debian packages {} (apt-get install {})",
        missing.join(", "),
        missing.join(" ")
    );
    unavailable(require, format_args!("{text}"));
    false
}

/// [`have_all`] for one program, under `SDI_REQUIRE_VM` (CI installs every
/// package the tests use).
pub fn have(program: &str, package: &str, what: &str) -> bool {
    have_all(what, &[(program, package)], "SDI_REQUIRE_VM")
}
