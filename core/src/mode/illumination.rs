//! What the light sources and the sensor modulation do for each mode, frame by
//! frame, and which simulator scene shows a mode off.

use super::ModeId;
use crate::modulation::{Illumination, ModulationPattern, SourceDrive};
use crate::scene::SceneSpec;

/// Where in the exposure the single-transition pattern of the temporal
/// gradient switches f from 0 to 1 (Fig. tempgradpatterns: 50/50, one transition).
pub const TEMPORAL_TRANSITION_AT: f64 = 0.5;

/// The scene used when a mode's own scene is not available in this build.
pub const FALLBACK_SCENE: &str = "flat-field";

impl ModeId {
    /// Illumination the sensor/LEDs use for frame `frame_index`.
    ///
    /// `frame_index` is the sensor sequence number ([`crate::Frame::sequence`])
    /// of the exposure being set up; the two-shot pipeline pairs frames by the
    /// same number (even = LS1 only, odd = LS2 only). In the two-shot frames the
    /// lit source is driven by f, so its light lands in I+ and reads positive,
    /// exactly as much as it would under the 50/50 snapshot drive.
    /// The temporal gradient uses the single-transition pattern with both LEDs
    /// off; every other mode is a snapshot (LS1 by f, LS2 by not-f).
    pub fn illumination(self, frame_index: u64, carrier_hz: f64) -> Illumination {
        match self {
            ModeId::TemporalGradient => Illumination {
                modulation: ModulationPattern::single_transition(TEMPORAL_TRANSITION_AT),
                ls1: SourceDrive::Off,
                ls2: SourceDrive::Off,
            },
            ModeId::TwoShot => {
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
            ModeId::Raw
            | ModeId::DirectOnly
            | ModeId::BipolarColour
            | ModeId::Separation
            | ModeId::DepthEdge
            | ModeId::DepthEdgeVertical
            | ModeId::SpatialGradient => Illumination::snapshot(carrier_hz),
        }
    }

    /// Name of the simulator scene that shows this mode off.
    pub fn default_scene_name(self) -> &'static str {
        match self {
            ModeId::Raw => "flat-field",
            ModeId::DirectOnly => "polarization",
            ModeId::BipolarColour | ModeId::Separation => "colour-chart",
            ModeId::DepthEdge => "depth-edge",
            ModeId::DepthEdgeVertical => "depth-edge-vertical",
            ModeId::SpatialGradient => "birefringent",
            ModeId::TemporalGradient => "fan-pellets",
            // The paper compares single- and two-shot edge imaging (section 5.3).
            ModeId::TwoShot => "depth-edge",
        }
    }

    /// The simulator scene that shows this mode off; falls back to the flat
    /// field only when that scene is not available in this build.
    pub fn default_scene(self) -> SceneSpec {
        SceneSpec::from_name(self.default_scene_name())
            .or_else(|| SceneSpec::from_name(FALLBACK_SCENE))
            .unwrap_or(SceneSpec::FlatField {
                ls1_electrons_per_us: 4.0,
                ls2_electrons_per_us: 2.0,
            })
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

    #[test]
    fn every_mode_has_a_scene() {
        for m in ModeId::ALL {
            let s = m.default_scene();
            assert!(s.name() == m.default_scene_name() || s.name() == FALLBACK_SCENE);
        }
    }
}
