//! The list of modes and, for each, its one entry in the table of what it is:
//! the setup it expects, how it lights the scene, the scene that shows it
//! off and the pipeline it runs ([`ModeSpec`]).

use super::illumination::IlluminationKind;
use super::spec::{ModeSpec, PhysicalSetup, PipelineKind};
use crate::scene::SceneId;

crate::named_enum! {
    /// Every mode SDI can run, named in kebab-case ("depth-edge"): one table
    /// (strum's) for `FromStr`, `Display`, serde and the list of names.
    #[strum(
        serialize_all = "kebab-case",
        parse_err_ty = UnknownMode,
        parse_err_fn = unknown_mode
    )]
    pub enum ModeId {
        /// The sensor's difference image as is (dark-frame subtracted).
        Raw,
        /// Polarization difference: direct reflection only (section 5.1).
        DirectOnly,
        /// Red LS1, blue LS2: bipolar colour (section 5.2).
        BipolarColour,
        /// Sources left and right of the lens: vertical depth edges (section 5.3).
        DepthEdge,
        /// Sources above and below the lens: horizontal depth edges (section 5.3).
        DepthEdgeVertical,
        /// Birefringent crystal, crossed polarized sources (section 5.4).
        SpatialGradient,
        /// Single-transition modulation, no active light (section 5.4).
        TemporalGradient,
        /// LS1 and LS2 in alternate frames, subtracted after the ADC (section 5.5 baseline).
        TwoShot,
        /// Red LS1, blue LS2 as bipolar colour; I+ and I- recovered live (section 6).
        Separation,
    }
}

fn unknown_mode(given: &str) -> UnknownMode {
    UnknownMode {
        given: given.to_owned(),
    }
}

/// A name that is not a mode; carries the valid names for the error message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown mode '{given}'; valid modes: {}", ModeId::NAMES.join(", "))]
pub struct UnknownMode {
    pub given: String,
}

/// The red/blue setup of the colour modes (section 5.2).
const RED_BLUE: PhysicalSetup = PhysicalSetup {
    ls1: "red LEDs",
    ls2: "blue LEDs",
    optics: "IR-cut filter removed",
};

impl ModeId {
    /// What this mode is; one entry per mode.
    pub fn spec(self) -> &'static ModeSpec {
        match self {
            ModeId::Raw => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "any source, in phase",
                    ls2: "any source, out of phase",
                    optics: "none",
                },
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::FlatField,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::DirectOnly => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "white LEDs, linear polarizer parallel to the analyzer",
                    ls2: "white LEDs, linear polarizer crossed with the analyzer",
                    optics: "linear analyzer in front of the lens",
                },
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::Polarization,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::BipolarColour => &ModeSpec {
                setup: RED_BLUE,
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::ColourChart,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::DepthEdge => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "identical LEDs left of the lens",
                    ls2: "identical LEDs right of the lens",
                    optics: "none; source spacing sets the edge width",
                },
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::DepthEdge,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::DepthEdgeVertical => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "identical LEDs above the lens",
                    ls2: "identical LEDs below the lens",
                    optics: "none; source spacing sets the edge width",
                },
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::DepthEdgeVertical,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::SpatialGradient => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "LEDs with a linear polarizer at 0 degrees",
                    ls2: "LEDs with a linear polarizer at 90 degrees",
                    optics: "birefringent crystal (1 mm YVO4, tilted 20 degrees) on the sensor",
                },
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::Birefringent,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::TemporalGradient => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "off",
                    ls2: "off",
                    optics: "none; single-transition modulation, scene lit by ambient light",
                },
                illumination: IlluminationKind::SingleTransition,
                default_scene: SceneId::FanPellets,
                pipeline: PipelineKind::Snapshot,
            },
            ModeId::TwoShot => &ModeSpec {
                setup: PhysicalSetup {
                    ls1: "on in even frames only",
                    ls2: "on in odd frames only",
                    optics: "as the mode being compared against",
                },
                illumination: IlluminationKind::Alternating,
                // The paper compares single- and two-shot edge imaging (section 5.3).
                default_scene: SceneId::DepthEdge,
                pipeline: PipelineKind::TwoShot,
            },
            ModeId::Separation => &ModeSpec {
                setup: RED_BLUE,
                illumination: IlluminationKind::Snapshot,
                default_scene: SceneId::ColourChart,
                pipeline: PipelineKind::Separation,
            },
        }
    }

    /// Every mode's name, in declaration order.
    pub fn names() -> Vec<&'static str> {
        Self::NAMES.to_vec()
    }

    pub fn from_name(name: &str) -> Result<Self, UnknownMode> {
        name.parse()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strum::IntoEnumIterator;

    #[derive(Debug, serde::Serialize, serde::Deserialize)]
    struct Wrap {
        mode: ModeId,
    }

    #[test]
    fn names_round_trip() {
        for m in ModeId::iter() {
            assert_eq!(ModeId::from_name(m.name()), Ok(m));
        }
        assert_eq!(ModeId::names().len(), ModeId::iter().count());
        let json = toml::to_string(&Wrap {
            mode: ModeId::DepthEdgeVertical,
        })
        .unwrap();
        assert_eq!(json.trim(), "mode = \"depth-edge-vertical\"");
        assert_eq!(
            toml::from_str::<Wrap>(&json).unwrap().mode,
            ModeId::DepthEdgeVertical
        );
        let bad = toml::from_str::<Wrap>("mode = \"Raw\"")
            .unwrap_err()
            .to_string();
        assert!(bad.contains("valid modes"), "{bad}");
        let err = ModeId::from_name("nope").unwrap_err().to_string();
        assert!(err.contains("depth-edge") && err.contains("nope"));
    }
}
