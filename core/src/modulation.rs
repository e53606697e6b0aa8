//! Sensor modulation f(t) and how each light source is driven (section 3,
//! Fig. tempgradpatterns).
//!
//! A pattern is a list of segments over normalized exposure time u in [0, 1];
//! within a segment f(t) is a square wave far faster than the scene with the
//! segment's duty (the fraction of time f = 1). The 50/50 high-frequency
//! pattern is one segment of duty 0.5; the single-transition pattern for
//! temporal gradients is duty 0 then duty 1. New codes are new segment lists.

use serde::{Deserialize, Serialize};

/// One stretch of the exposure with a constant duty of f(t).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    /// Start, as a fraction of the exposure.
    pub start: f64,
    /// End, as a fraction of the exposure (> start).
    pub end: f64,
    /// Fraction of the time within the segment where f(t) = 1.
    pub duty: f64,
}

/// f(t) over one exposure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModulationPattern {
    /// Contiguous segments covering [0, 1].
    pub segments: Vec<Segment>,
    /// Carrier frequency of the square wave inside segments, Hz (metadata for
    /// hardware; the model assumes it is much faster than the scene).
    pub carrier_hz: f64,
}

impl ModulationPattern {
    /// The default: a 50/50 high-frequency square wave over the whole exposure.
    pub fn square_wave(carrier_hz: f64) -> Self {
        Self {
            segments: vec![Segment {
                start: 0.0,
                end: 1.0,
                duty: 0.5,
            }],
            carrier_hz,
        }
    }

    /// One transition at fraction `at` of the exposure: f = 0 before, 1 after.
    /// Light arriving late lands in I+, early light in I- (temporal gradient).
    pub fn single_transition(at: f64) -> Self {
        let at = at.clamp(0.0, 1.0);
        Self {
            segments: vec![
                Segment {
                    start: 0.0,
                    end: at,
                    duty: 0.0,
                },
                Segment {
                    start: at,
                    end: 1.0,
                    duty: 1.0,
                },
            ],
            carrier_hz: 0.0,
        }
    }

    /// Mean of f(t) over [u0, u1] (fractions of the exposure), in [0, 1].
    pub fn duty_over(&self, u0: f64, u1: f64) -> f64 {
        let span = u1 - u0;
        if span <= 0.0 {
            return self.duty_at(u0);
        }
        let on: f64 = self
            .segments
            .iter()
            .map(|s| (s.end.min(u1) - s.start.max(u0)).max(0.0) * s.duty)
            .sum();
        (on / span).clamp(0.0, 1.0)
    }

    fn duty_at(&self, u: f64) -> f64 {
        self.segments
            .iter()
            .find(|s| u >= s.start && u < s.end)
            .or(self.segments.last())
            .map_or(0.0, |s| s.duty)
    }
}

/// How one light source follows the modulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SourceDrive {
    Off,
    /// Driven by f(t): emits only while f = 1, so all its light lands in I+.
    Modulated,
    /// Driven by not-f(t): emits only while f = 0, so all its light lands in I-.
    Inverted,
    /// Always on, uncorrelated with f: split by the duty like ambient light.
    Constant,
}

impl SourceDrive {
    /// Fractions of a source's full-power emission over a stretch of time that
    /// land in (I+, I-), given the mean duty of f over that stretch
    /// (eq. wellmeasurement with f in {0, 1}).
    #[inline]
    pub fn well_split(self, duty: f64) -> (f64, f64) {
        match self {
            SourceDrive::Off => (0.0, 0.0),
            SourceDrive::Modulated => (duty, 0.0),
            SourceDrive::Inverted => (0.0, 1.0 - duty),
            SourceDrive::Constant => (duty, 1.0 - duty),
        }
    }
}

/// What the light sources and sensor modulation do during one exposure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Illumination {
    pub modulation: ModulationPattern,
    /// LS1 (the "+" source).
    pub ls1: SourceDrive,
    /// LS2 (the "-" source).
    pub ls2: SourceDrive,
}

impl Illumination {
    /// Snapshot difference imaging: LS1 by f, LS2 by not-f, 50/50 square wave.
    pub fn snapshot(carrier_hz: f64) -> Self {
        Self {
            modulation: ModulationPattern::square_wave(carrier_hz),
            ls1: SourceDrive::Modulated,
            ls2: SourceDrive::Inverted,
        }
    }

    /// Both sources dark: what dark frames and passive modes use.
    pub fn dark(carrier_hz: f64) -> Self {
        Self {
            modulation: ModulationPattern::square_wave(carrier_hz),
            ls1: SourceDrive::Off,
            ls2: SourceDrive::Off,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_wave_has_half_duty_everywhere() {
        let p = ModulationPattern::square_wave(1e6);
        assert_eq!(p.duty_over(0.0, 1.0), 0.5);
        assert_eq!(p.duty_over(0.3, 0.31), 0.5);
    }

    #[test]
    fn single_transition_splits_exposure() {
        let p = ModulationPattern::single_transition(0.5);
        assert_eq!(p.duty_over(0.0, 0.5), 0.0);
        assert_eq!(p.duty_over(0.5, 1.0), 1.0);
        assert!((p.duty_over(0.25, 0.75) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn ambient_splits_evenly_under_square_wave() {
        let (p, m) = SourceDrive::Constant.well_split(0.5);
        assert_eq!(p, m);
    }
}
