//! The interface's errors are `sdi_api::SdiError` (`org.sdi.Error.*`), the
//! one definition shared with clients; this module adds what needs the daemon.

use sdi_core::mode::ModeId;

pub use sdi_api::error::SdiError;
use sdi_core::number::Number;

/// Checks that `value` is a finite number in `[lo, hi]`.
pub fn check_range(name: &str, value: f64, lo: f64, hi: f64, unit: &str) -> Result<f64, SdiError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(value)
    } else {
        Err(SdiError::OutOfRange(format!(
            "{name} = {} {unit} is out of range: allowed [{}, {}] {unit}",
            Number(value),
            Number(lo),
            Number(hi)
        )))
    }
}

/// `InvalidMode` for an unknown mode name, listing the valid ones.
pub fn invalid_mode(given: &str) -> SdiError {
    SdiError::InvalidMode(format!(
        "unknown mode '{}'; valid modes: {}",
        given.escape_debug(),
        ModeId::names().join(", ")
    ))
}
