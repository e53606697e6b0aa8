//! Typed calibration errors.

use crate::image::SizeMismatch;

/// Why a calibration step refused its input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    #[error("need at least {needed} {what}, got {got}")]
    TooFew {
        what: &'static str,
        needed: usize,
        got: usize,
    },
    #[error(transparent)]
    SizeMismatch(#[from] SizeMismatch),
    #[error("photon-transfer points are degenerate: all means equal")]
    Degenerate,
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
    #[error("calibration store: {0}")]
    Store(String),
}
