//! Typed errors of the separation estimators.

use crate::image::SizeMismatch;
use crate::sensor::{check, ParamError};

/// Why an estimator refused its input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SeparationError {
    #[error("need at least {needed} frames for a variance, got {got}")]
    TooFewFrames { needed: usize, got: usize },
    #[error(transparent)]
    SizeMismatch(#[from] SizeMismatch),
    #[error("empty image")]
    Empty,
    #[error(transparent)]
    Parameter(#[from] ParamError),
}

impl SeparationError {
    pub(crate) fn check(
        name: &'static str,
        value: f64,
        ok: bool,
        allowed: &'static str,
    ) -> Result<(), Self> {
        Ok(check(name, value, ok, allowed)?)
    }
}
