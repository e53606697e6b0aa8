//! The interface's errors are `sdi_api::SdiError` (`org.sdi.Error.*`), the
//! one definition shared with clients; this module adds what needs the
//! daemon: range checks, and the one mapping of the frame loop's typed
//! replies onto it.

pub use sdi_api::error::SdiError;
use sdi_core::mode::ModeId;
use sdi_core::number::Number;

use crate::backend::BackendError;
use crate::frame_loop::JobError;

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

/// The frame loop is gone: its command channel or a reply closed.
pub fn frame_loop_stopped<E>(_closed: E) -> SdiError {
    SdiError::DeviceUnavailable("the frame loop has stopped".into())
}

/// Capture settings the backend refused.
pub fn configure_refused(e: BackendError) -> SdiError {
    match e {
        BackendError::OutOfRange(m) => SdiError::OutOfRange(m),
        BackendError::Unavailable(m) => SdiError::DeviceUnavailable(m),
        other => SdiError::Failed(other.to_string()),
    }
}

/// A dark-frame capture that gave no dark frame.
pub fn dark_failed(e: JobError) -> SdiError {
    SdiError::DeviceUnavailable(e.to_string())
}

/// A photon-transfer calibration that gave no fit.
pub fn calibration_failed(e: JobError) -> SdiError {
    SdiError::Failed(format!("photon transfer: {e}"))
}

/// A phase calibration that gave no axis: the job's own words (too dim,
/// lights that cannot light LS1 alone, no phase quads).
pub fn phase_failed(e: JobError) -> SdiError {
    match e {
        JobError::Backend(BackendError::Unavailable(m)) => SdiError::DeviceUnavailable(m),
        other => SdiError::Failed(format!("phase calibration: {other}")),
    }
}
