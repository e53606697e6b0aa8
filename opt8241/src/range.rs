//! A range a setting must fall in, with what sets each end, and the error
//! naming it when a value falls outside ([`OutOfRange`]): the shape of
//! every limit in [`crate::limits`] and [`crate::pll`].

use sdi_core::number::Number;

/// A value the board cannot take, with the range it can.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{name} = {} {unit} is out of range for the board: allowed [{}, {}] {unit} ({why})",
    Number(*.value), Number(*.min), Number(*.max)
)]
pub struct OutOfRange {
    pub name: &'static str,
    pub value: f64,
    pub min: f64,
    pub max: f64,
    pub unit: &'static str,
    /// What sets the range's ends.
    pub why: String,
}

/// A closed range with what sets each end.
#[derive(Debug, Clone, PartialEq)]
pub struct Range {
    pub name: &'static str,
    pub unit: &'static str,
    pub min: f64,
    pub max: f64,
    pub min_set_by: &'static str,
    pub max_set_by: &'static str,
}

impl Range {
    /// `value` if finite and inside, else an [`OutOfRange`] naming the range.
    pub fn check(&self, value: f64) -> Result<f64, OutOfRange> {
        if value.is_finite() && value >= self.min && value <= self.max {
            Ok(value)
        } else {
            Err(OutOfRange {
                name: self.name,
                value,
                min: self.min,
                max: self.max,
                unit: self.unit,
                why: format!(
                    "low end: {}; high end: {}",
                    self.min_set_by, self.max_set_by
                ),
            })
        }
    }

    pub fn bounds(&self) -> (f64, f64) {
        (self.min, self.max)
    }
}
