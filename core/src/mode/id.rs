//! The list of modes, their names, and the physical setup each one expects.

use serde::Serialize;

/// Every mode SDI can run, named in kebab-case ("depth-edge"): one table
/// (strum's) for `FromStr`, `Display`, serde and the list of names.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Hash,
    strum::EnumString,
    strum::Display,
    strum::IntoStaticStr,
    strum::VariantNames,
    strum::EnumIter,
    strum::EnumMessage,
)]
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

crate::serde_by_name!(ModeId);

fn unknown_mode(given: &str) -> UnknownMode {
    UnknownMode {
        given: given.to_owned(),
    }
}

/// A name that is not a mode; carries the valid names for the error message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown mode '{given}'; valid modes: {}", ModeId::names().join(", "))]
pub struct UnknownMode {
    pub given: String,
}

/// What the operator must set up for a mode: the daemon cannot move optics.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct PhysicalSetup {
    pub ls1: &'static str,
    pub ls2: &'static str,
    pub optics: &'static str,
}

impl ModeId {
    pub const ALL: [ModeId; 9] = [
        ModeId::Raw,
        ModeId::DirectOnly,
        ModeId::BipolarColour,
        ModeId::DepthEdge,
        ModeId::DepthEdgeVertical,
        ModeId::SpatialGradient,
        ModeId::TemporalGradient,
        ModeId::TwoShot,
        ModeId::Separation,
    ];

    pub fn name(self) -> &'static str {
        self.into()
    }

    pub fn names() -> Vec<&'static str> {
        <Self as strum::VariantNames>::VARIANTS.to_vec()
    }

    pub fn from_name(name: &str) -> Result<Self, UnknownMode> {
        name.parse()
    }

    pub fn setup(self) -> PhysicalSetup {
        let (ls1, ls2, optics) = match self {
            ModeId::Raw => ("any source, in phase", "any source, out of phase", "none"),
            ModeId::DirectOnly => (
                "white LEDs, linear polarizer parallel to the analyzer",
                "white LEDs, linear polarizer crossed with the analyzer",
                "linear analyzer in front of the lens",
            ),
            ModeId::BipolarColour | ModeId::Separation => {
                ("red LEDs", "blue LEDs", "IR-cut filter removed")
            }
            ModeId::DepthEdge => (
                "identical LEDs left of the lens",
                "identical LEDs right of the lens",
                "none; source spacing sets the edge width",
            ),
            ModeId::DepthEdgeVertical => (
                "identical LEDs above the lens",
                "identical LEDs below the lens",
                "none; source spacing sets the edge width",
            ),
            ModeId::SpatialGradient => (
                "LEDs with a linear polarizer at 0 degrees",
                "LEDs with a linear polarizer at 90 degrees",
                "birefringent crystal (1 mm YVO4, tilted 20 degrees) on the sensor",
            ),
            ModeId::TemporalGradient => (
                "off",
                "off",
                "none; single-transition modulation, scene lit by ambient light",
            ),
            ModeId::TwoShot => (
                "on in even frames only",
                "on in odd frames only",
                "as the mode being compared against",
            ),
        };
        PhysicalSetup { ls1, ls2, optics }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Serialize, serde::Deserialize)]
    struct Wrap {
        mode: ModeId,
    }

    #[test]
    fn names_round_trip() {
        for m in ModeId::ALL {
            assert_eq!(ModeId::from_name(m.name()), Ok(m));
        }
        assert_eq!(ModeId::names().len(), ModeId::ALL.len());
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
