//! The scenes the simulator can build, by name: the one table of scene
//! names, which `sdid.toml`, `sdid --scene` and `sdictl sim --scene` parse.

use super::{SceneSpec, SourcePlacement};

crate::named_enum! {
    /// A scene, named in kebab-case ("colour-chart").
    #[strum(
        serialize_all = "kebab-case",
        parse_err_ty = UnknownScene,
        parse_err_fn = unknown_scene
    )]
    pub enum SceneId {
        /// Uniform LS1 and LS2 rates.
        FlatField,
        /// 24-patch colour chart (section 5.2).
        ColourChart,
        /// Specular and depolarizing materials (section 5.1).
        Polarization,
        /// Objects at several depths, sources left and right (section 5.3).
        DepthEdge,
        /// As depth-edge, sources above and below.
        DepthEdgeVertical,
        /// Resolution chart through a birefringent crystal (section 5.4).
        Birefringent,
        /// Rotating fan and bouncing pellets under ambient light (section 5.4).
        FanPellets,
    }
}

fn unknown_scene(given: &str) -> UnknownScene {
    UnknownScene {
        given: given.to_owned(),
    }
}

/// A name that is not a scene; the message lists the valid names.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown scene '{given}': use {}", SceneId::NAMES.join(", "))]
pub struct UnknownScene {
    pub given: String,
}

impl SceneId {
    /// The scene with its default parameters.
    pub fn spec(self) -> SceneSpec {
        let depth_edge = |placement| SceneSpec::DepthEdge {
            source_spacing_mm: 100.0,
            placement,
            source_electrons_per_us: 12.0,
        };
        match self {
            SceneId::FlatField => SceneSpec::FlatField {
                ls1_electrons_per_us: 4.0,
                ls2_electrons_per_us: 2.0,
            },
            SceneId::ColourChart => SceneSpec::ColourChart {
                red_led_electrons_per_us: 12.0,
                blue_led_electrons_per_us: 12.0,
            },
            SceneId::Polarization => SceneSpec::Polarization {
                source_electrons_per_us: 12.0,
            },
            SceneId::DepthEdge => depth_edge(SourcePlacement::Horizontal),
            SceneId::DepthEdgeVertical => depth_edge(SourcePlacement::Vertical),
            SceneId::Birefringent => SceneSpec::Birefringent {
                source_electrons_per_us: 12.0,
                displacement_px: 1.0,
            },
            SceneId::FanPellets => SceneSpec::FanPellets {
                background_electrons_per_us: 1.0,
                object_electrons_per_us: 12.0,
                fan_rpm: 1500.0,
                pellets: 12,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strum::IntoEnumIterator;

    #[test]
    fn names_parse_and_an_unknown_one_lists_them() {
        for id in SceneId::iter() {
            assert_eq!(id.name().parse(), Ok(id));
        }
        assert_eq!(SceneId::NAMES.len(), SceneId::iter().count());
        let e = "lab".parse::<SceneId>().unwrap_err().to_string();
        assert_eq!(
            e,
            "unknown scene 'lab': use flat-field, colour-chart, polarization, \
             depth-edge, depth-edge-vertical, birefringent, fan-pellets"
        );
    }
}
