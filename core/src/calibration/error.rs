//! Typed calibration errors.

/// Why a calibration step refused its input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    #[error("need at least {needed} {what}, got {got}")]
    TooFew {
        what: &'static str,
        needed: usize,
        got: usize,
    },
    #[error("frame is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    SizeMismatch {
        want_w: usize,
        want_h: usize,
        got_w: usize,
        got_h: usize,
    },
    #[error("photon-transfer points are degenerate: all means equal")]
    Degenerate,
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
    #[error("calibration store: {0}")]
    Store(String),
}
