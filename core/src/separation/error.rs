//! Typed errors of the separation estimators.

use crate::image::SizeMismatch;

/// Why an estimator refused its input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SeparationError {
    #[error("need at least {needed} frames for a variance, got {got}")]
    TooFewFrames { needed: usize, got: usize },
    #[error(transparent)]
    SizeMismatch(#[from] SizeMismatch),
    #[error("empty image")]
    Empty,
    #[error("{name} = {} is out of range: expected {allowed}", crate::number::Number(*.value))]
    Parameter {
        name: &'static str,
        value: f64,
        allowed: &'static str,
    },
}

impl SeparationError {
    pub(crate) fn check(
        name: &'static str,
        value: f64,
        ok: bool,
        allowed: &'static str,
    ) -> Result<(), Self> {
        if ok && value.is_finite() {
            Ok(())
        } else {
            Err(Self::Parameter {
                name,
                value,
                allowed,
            })
        }
    }
}
