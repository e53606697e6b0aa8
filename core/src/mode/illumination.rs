//! What the light sources and the sensor modulation do frame by frame, for
//! each kind of drive a mode can ask for ([`super::ModeSpec::illumination`]).

use super::ModeId;
use crate::modulation::{Illumination, ModulationPattern, SourceDrive};

/// Where in the exposure the single-transition pattern of the temporal
/// gradient switches f from 0 to 1 (Fig. tempgradpatterns: 50/50, one transition).
pub const TEMPORAL_TRANSITION_AT: f64 = 0.5;

/// How a mode drives LS1, LS2 and f(t) (section 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IlluminationKind {
    /// 50/50 square wave, LS1 by f, LS2 by not-f: the snapshot difference.
    Snapshot,
    /// LS1 alone in even frames, LS2 alone in odd ones, each by f (two-shot).
    Alternating,
    /// Both sources off, f a single transition at [`TEMPORAL_TRANSITION_AT`]
    /// (temporal gradient).
    SingleTransition,
}

impl IlluminationKind {
    /// The drive for frame `frame_index`.
    ///
    /// `frame_index` is the sensor sequence number ([`crate::Frame::sequence`])
    /// of the exposure being set up; the two-shot pipeline pairs frames by the
    /// same number (even = LS1 only, odd = LS2 only). In alternating frames the
    /// lit source is driven by f, so its light lands in I+ and reads positive,
    /// exactly as much as it would under the 50/50 snapshot drive.
    pub fn at(self, frame_index: u64, carrier_hz: f64) -> Illumination {
        match self {
            IlluminationKind::Snapshot => Illumination::snapshot(carrier_hz),
            IlluminationKind::Alternating => {
                let (ls1, ls2) = if frame_index & 1 == 0 {
                    (SourceDrive::Modulated, SourceDrive::Off)
                } else {
                    (SourceDrive::Off, SourceDrive::Modulated)
                };
                Illumination {
                    modulation: ModulationPattern::square_wave(carrier_hz),
                    ls1,
                    ls2,
                }
            }
            IlluminationKind::SingleTransition => Illumination {
                modulation: ModulationPattern::single_transition(TEMPORAL_TRANSITION_AT),
                ls1: SourceDrive::Off,
                ls2: SourceDrive::Off,
            },
        }
    }
}

impl ModeId {
    /// Illumination the sensor/LEDs use for frame `frame_index`
    /// ([`IlluminationKind::at`] of this mode's kind).
    pub fn illumination(self, frame_index: u64, carrier_hz: f64) -> Illumination {
        self.spec().illumination.at(frame_index, carrier_hz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_shot_alternates_sources() {
        let a = ModeId::TwoShot.illumination(10, 1e6);
        let b = ModeId::TwoShot.illumination(11, 1e6);
        assert_eq!((a.ls1, a.ls2), (SourceDrive::Modulated, SourceDrive::Off));
        assert_eq!((b.ls1, b.ls2), (SourceDrive::Off, SourceDrive::Modulated));
    }

    #[test]
    fn temporal_gradient_is_passive_single_transition() {
        let i = ModeId::TemporalGradient.illumination(0, 1e6);
        assert_eq!((i.ls1, i.ls2), (SourceDrive::Off, SourceDrive::Off));
        assert_eq!(i.modulation.duty_over(0.0, 0.5), 0.0);
        assert_eq!(i.modulation.duty_over(0.5, 1.0), 1.0);
    }
}
