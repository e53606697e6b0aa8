//! The ranges of the capture settings a client may change (exposure, frame
//! rate, modulation), defined once: the sensor model, `sdid`'s command line
//! and configuration, and the D-Bus setters all check against these.
//! A backend may narrow them (the board's laser-safety limits), never widen.

use crate::number::Number;

/// A closed range `[min, max]` of one setting, with its name and unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureRange {
    /// The setting's name as in `sdid.toml` and on the command line.
    pub name: &'static str,
    pub min: f64,
    pub max: f64,
    pub unit: &'static str,
    /// `[min, max] unit`, for messages that need a static string.
    pub allowed: &'static str,
}

/// A value outside its [`CaptureRange`] (NaN and infinities included).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{name} = {} {unit} is out of range: allowed [{}, {}] {unit}",
    Number(*.value), Number(*.min), Number(*.max)
)]
pub struct OutOfRange {
    pub name: &'static str,
    pub value: f64,
    pub min: f64,
    pub max: f64,
    pub unit: &'static str,
}

impl CaptureRange {
    /// True for a finite value within the range.
    pub fn contains(&self, value: f64) -> bool {
        value.is_finite() && value >= self.min && value <= self.max
    }

    /// `value` if it is inside, else why not.
    pub fn check(&self, value: f64) -> Result<f64, OutOfRange> {
        if self.contains(value) {
            Ok(value)
        } else {
            Err(OutOfRange {
                name: self.name,
                value,
                min: self.min,
                max: self.max,
                unit: self.unit,
            })
        }
    }

    /// `(min, max)`, as backends' limits hold it.
    pub const fn bounds(&self) -> (f64, f64) {
        (self.min, self.max)
    }
}

/// Exposure per frame.
pub const EXPOSURE_US: CaptureRange = CaptureRange {
    name: "exposure_us",
    min: 1.0,
    max: 1_000_000.0,
    unit: "us",
    allowed: "[1, 1000000] us",
};

/// Frame rate: 0.1 Hz (one frame in 10 s) to 240 Hz.
pub const FRAME_RATE_HZ: CaptureRange = CaptureRange {
    name: "frame_rate_hz",
    min: 0.1,
    max: 240.0,
    unit: "Hz",
    allowed: "[0.1, 240] Hz",
};

/// Modulation (carrier) frequency of f(t).
pub const MODULATION_HZ: CaptureRange = CaptureRange {
    name: "modulation_hz",
    min: 1e3,
    max: 100e6,
    unit: "Hz",
    allowed: "[1000, 100000000] Hz",
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_are_inside_and_non_finite_is_outside() {
        for r in [EXPOSURE_US, FRAME_RATE_HZ, MODULATION_HZ] {
            assert_eq!(r.check(r.min), Ok(r.min));
            assert_eq!(r.check(r.max), Ok(r.max));
            for bad in [f64::NAN, f64::INFINITY, -r.max, r.max * 1.01, r.min * 0.99] {
                let e = r.check(bad).unwrap_err();
                assert!(e.to_string().contains(r.name), "{e}");
            }
        }
        assert!(!FRAME_RATE_HZ.contains(241.0) && !FRAME_RATE_HZ.contains(0.05));
    }
}
