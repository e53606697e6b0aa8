//! Deterministic synthetic scenes. Each models only what its mode needs and
//! reports photoelectron rates per pixel at one instant.

mod flat_field;

pub use flat_field::FlatField;

use serde::{Deserialize, Serialize};

use crate::image::Image;

/// Photoelectron rates arriving at each pixel at one instant, electrons per
/// microsecond, for each source at full power (before the modulation splits
/// them between the wells). Channels a scene does not have stay `None`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Radiance {
    pub ls1: Option<Image<f32>>,
    pub ls2: Option<Image<f32>>,
    /// Light uncorrelated with the modulation (room light, sun, a passive scene).
    pub ambient: Option<Image<f32>>,
}

/// A scene the simulator can image.
pub trait Scene: Send {
    fn width(&self) -> usize;
    fn height(&self) -> usize;
    /// True when nothing moves: the simulator then integrates in one step.
    fn is_static(&self) -> bool;
    /// Rates at time `t_us` (microseconds since the start of the run).
    /// Implementations reuse the buffers already in `out`.
    fn render(&self, t_us: f64, out: &mut Radiance);
}

/// Which scene to build, with its parameters. Deterministic given the seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum SceneSpec {
    /// Uniform LS1 and LS2 rates (noise and calibration work).
    FlatField {
        ls1_electrons_per_us: f64,
        ls2_electrons_per_us: f64,
    },
}

impl SceneSpec {
    /// Names accepted on command lines.
    pub const NAMES: &'static [&'static str] = &["flat-field"];

    pub fn name(&self) -> &'static str {
        match self {
            SceneSpec::FlatField { .. } => "flat-field",
        }
    }

    /// The scene of that name with its default parameters.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "flat-field" => Some(SceneSpec::FlatField {
                ls1_electrons_per_us: 4.0,
                ls2_electrons_per_us: 2.0,
            }),
            _ => None,
        }
    }

    /// Builds the scene at the sensor's resolution.
    pub fn build(&self, width: usize, height: usize, _seed: u64) -> Box<dyn Scene> {
        match *self {
            SceneSpec::FlatField {
                ls1_electrons_per_us,
                ls2_electrons_per_us,
            } => Box::new(FlatField::new(
                width,
                height,
                ls1_electrons_per_us as f32,
                ls2_electrons_per_us as f32,
            )),
        }
    }
}
