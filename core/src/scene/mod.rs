//! Deterministic synthetic scenes. Each models only what its mode needs and
//! reports photoelectron rates per pixel at one instant.

mod birefringent;
mod colour_chart;
mod depth_edge;
mod fan_pellets;
mod flat_field;
mod id;
mod params;
mod polarization;

pub use birefringent::BirefringentChart;
pub use colour_chart::ColourChart;
pub use depth_edge::{DepthEdgeScene, SourcePlacement};
pub use fan_pellets::{FanPellets, FanPelletsParams};
pub use flat_field::FlatField;
pub use id::{SceneId, UnknownScene};
pub use params::SceneParamError;
pub use polarization::{Components, PolarizationScene, Region};

/// Scene-specific constants and helpers (layouts, reflectances) for tests
/// and tools that need the ground truth.
pub mod layout {
    pub use super::birefringent::{BACKGROUND_REFLECTANCE, MARKER_REFLECTANCE};
    pub use super::colour_chart::{
        patch_reflectance, COLUMNS, PATCHES, ROWS, SURROUND_REFLECTANCE,
    };
    pub use super::depth_edge::{Object, Shape, OBJECTS, WALL_ALBEDO, WALL_DEPTH_MM};
}

use serde::{Deserialize, Serialize};

use crate::image::Image;
use crate::sensor::{check, ParamError};

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
    /// Moving scenes that can integrate their motion: the mean rates over
    /// [t0_us, t1_us] into `out`, at least as accurate as the mean of
    /// `samples` renders at evenly spaced midpoints. False (the default):
    /// the caller averages renders itself.
    fn render_mean(
        &mut self,
        _t0_us: f64,
        _t1_us: f64,
        _samples: usize,
        _out: &mut Radiance,
    ) -> bool {
        false
    }
    /// Depth of the surface seen at each pixel, metres (sources beside the
    /// lens: light travels twice this), for scenes that model depth.
    fn depth_m(&self) -> Option<Image<f32>> {
        None
    }
}

/// A scene that does not move and is lit only by LS1 and LS2, described
/// pixel by pixel. Every such scene is a [`Scene`] through the impl below.
pub trait StillScene: Send {
    /// Width and height, pixels.
    fn size(&self) -> (usize, usize);
    /// LS1 and LS2 rates at pixel (x, y), electrons per microsecond.
    fn rates_at(&self, x: usize, y: usize) -> (f32, f32);
    /// Depth of the surface at pixel (x, y), metres; None: no depth modelled.
    fn depth_at(&self, _x: usize, _y: usize) -> Option<f32> {
        None
    }
}

impl<T: StillScene> Scene for T {
    fn width(&self) -> usize {
        self.size().0
    }

    fn height(&self) -> usize {
        self.size().1
    }

    fn is_static(&self) -> bool {
        true
    }

    fn render(&self, _t_us: f64, out: &mut Radiance) {
        let (w, h) = self.size();
        let mut ls1 = reuse(out.ls1.take(), w, h);
        let mut ls2 = reuse(out.ls2.take(), w, h);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                (ls1.data[i], ls2.data[i]) = self.rates_at(x, y);
            }
        }
        out.ls1 = Some(ls1);
        out.ls2 = Some(ls2);
        out.ambient = None;
    }

    fn depth_m(&self) -> Option<Image<f32>> {
        let (w, h) = self.size();
        self.depth_at(0, 0)?;
        let mut d = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                d.data[y * w + x] = self.depth_at(x, y).unwrap_or(0.0);
            }
        }
        Some(d)
    }
}

/// `img` if it already has the size, else a new zeroed image.
fn reuse(img: Option<Image<f32>>, width: usize, height: usize) -> Image<f32> {
    match img {
        Some(i) if i.width == width && i.height == height => i,
        _ => Image::new(width, height),
    }
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
    /// 24-patch colour chart, red LEDs on LS1, blue on LS2 (section 5.2).
    ColourChart {
        red_led_electrons_per_us: f64,
        blue_led_electrons_per_us: f64,
    },
    /// Specular and depolarizing materials under crossed polarizers (section 5.1).
    Polarization { source_electrons_per_us: f64 },
    /// Objects at several depths, sources on opposite sides of the lens
    /// (section 5.3). Named "depth-edge" (left/right) or
    /// "depth-edge-vertical" (above/below) by `placement`.
    DepthEdge {
        source_spacing_mm: f64,
        placement: SourcePlacement,
        source_electrons_per_us: f64,
    },
    /// Resolution chart seen through a birefringent crystal (section 5.4).
    Birefringent {
        source_electrons_per_us: f64,
        displacement_px: f64,
    },
    /// Rotating fan and bouncing pellets under ambient light only (section 5.4).
    FanPellets {
        background_electrons_per_us: f64,
        object_electrons_per_us: f64,
        fan_rpm: f64,
        pellets: u32,
    },
}

fn check_rate(name: &'static str, value: f64) -> Result<(), ParamError> {
    check(name, value, (0.0..=1e6).contains(&value), "[0, 1e6]")
}

impl SceneSpec {
    /// Which scene this is.
    pub fn id(&self) -> SceneId {
        match self {
            SceneSpec::FlatField { .. } => SceneId::FlatField,
            SceneSpec::ColourChart { .. } => SceneId::ColourChart,
            SceneSpec::Polarization { .. } => SceneId::Polarization,
            SceneSpec::DepthEdge { placement, .. } => match placement {
                SourcePlacement::Horizontal => SceneId::DepthEdge,
                SourcePlacement::Vertical => SceneId::DepthEdgeVertical,
            },
            SceneSpec::Birefringent { .. } => SceneId::Birefringent,
            SceneSpec::FanPellets { .. } => SceneId::FanPellets,
        }
    }

    pub fn name(&self) -> &'static str {
        self.id().name()
    }

    /// The scene of that name with its default parameters.
    pub fn from_name(name: &str) -> Option<Self> {
        name.parse().ok().map(SceneId::spec)
    }

    /// Rejects NaN, negative rates and out-of-range geometry.
    pub fn validate(&self) -> Result<(), ParamError> {
        match *self {
            SceneSpec::FlatField {
                ls1_electrons_per_us,
                ls2_electrons_per_us,
            } => {
                check_rate("ls1_electrons_per_us", ls1_electrons_per_us)?;
                check_rate("ls2_electrons_per_us", ls2_electrons_per_us)
            }
            SceneSpec::ColourChart {
                red_led_electrons_per_us,
                blue_led_electrons_per_us,
            } => {
                check_rate("red_led_electrons_per_us", red_led_electrons_per_us)?;
                check_rate("blue_led_electrons_per_us", blue_led_electrons_per_us)
            }
            SceneSpec::Polarization {
                source_electrons_per_us,
            } => check_rate("source_electrons_per_us", source_electrons_per_us),
            SceneSpec::DepthEdge {
                source_spacing_mm,
                source_electrons_per_us,
                ..
            } => {
                let s = source_spacing_mm;
                check(
                    "source_spacing_mm",
                    s,
                    (0.0..=2000.0).contains(&s),
                    "[0, 2000] mm",
                )?;
                check_rate("source_electrons_per_us", source_electrons_per_us)
            }
            SceneSpec::Birefringent {
                source_electrons_per_us,
                displacement_px,
            } => {
                let d = displacement_px;
                check(
                    "displacement_px",
                    d,
                    (-8.0..=8.0).contains(&d),
                    "[-8, 8] px",
                )?;
                check_rate("source_electrons_per_us", source_electrons_per_us)
            }
            SceneSpec::FanPellets {
                background_electrons_per_us,
                object_electrons_per_us,
                fan_rpm,
                pellets,
            } => {
                check_rate("background_electrons_per_us", background_electrons_per_us)?;
                check_rate("object_electrons_per_us", object_electrons_per_us)?;
                check(
                    "fan_rpm",
                    fan_rpm,
                    fan_rpm.abs() <= 100_000.0,
                    "[-1e5, 1e5] rpm",
                )?;
                let p = pellets as f64;
                check("pellets", p, pellets <= 1000, "0..=1000")
            }
        }
    }

    /// Builds the scene at the sensor's resolution.
    pub fn build(&self, width: usize, height: usize, seed: u64) -> Box<dyn Scene> {
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
            SceneSpec::ColourChart {
                red_led_electrons_per_us,
                blue_led_electrons_per_us,
            } => Box::new(ColourChart::new(
                width,
                height,
                red_led_electrons_per_us as f32,
                blue_led_electrons_per_us as f32,
            )),
            SceneSpec::Polarization {
                source_electrons_per_us,
            } => Box::new(PolarizationScene::new(
                width,
                height,
                source_electrons_per_us as f32,
            )),
            SceneSpec::DepthEdge {
                source_spacing_mm,
                placement,
                source_electrons_per_us,
            } => Box::new(DepthEdgeScene::new(
                width,
                height,
                source_spacing_mm as f32,
                placement,
                source_electrons_per_us as f32,
            )),
            SceneSpec::Birefringent {
                source_electrons_per_us,
                displacement_px,
            } => Box::new(BirefringentChart::new(
                width,
                height,
                source_electrons_per_us as f32,
                displacement_px as f32,
            )),
            SceneSpec::FanPellets {
                background_electrons_per_us,
                object_electrons_per_us,
                fan_rpm,
                pellets,
            } => Box::new(FanPellets::new(
                width,
                height,
                FanPelletsParams {
                    background_electrons_per_us: background_electrons_per_us as f32,
                    object_electrons_per_us: object_electrons_per_us as f32,
                    fan_rpm: fan_rpm as f32,
                    pellets: pellets as usize,
                },
                seed,
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strum::IntoEnumIterator;

    #[test]
    fn every_name_round_trips_and_builds() {
        for id in SceneId::iter() {
            let spec = id.spec();
            assert_eq!(spec.id(), id);
            assert_eq!(SceneSpec::from_name(id.name()), Some(spec.clone()));
            spec.validate().unwrap();
            let toml = toml::to_string(&spec).unwrap();
            let back: SceneSpec = toml::from_str(&toml).unwrap();
            assert_eq!(back, spec);
            let scene = spec.build(32, 24, 1);
            let mut r = Radiance::default();
            scene.render(0.0, &mut r);
            assert_eq!((scene.width(), scene.height()), (32, 24));
        }
        assert!(SceneSpec::from_name("nope").is_none());
    }

    #[test]
    fn bad_parameters_are_rejected() {
        let bad = [
            SceneSpec::FlatField {
                ls1_electrons_per_us: f64::NAN,
                ls2_electrons_per_us: 1.0,
            },
            SceneSpec::ColourChart {
                red_led_electrons_per_us: -1.0,
                blue_led_electrons_per_us: 1.0,
            },
            SceneSpec::DepthEdge {
                source_spacing_mm: f64::INFINITY,
                placement: SourcePlacement::Vertical,
                source_electrons_per_us: 1.0,
            },
            SceneSpec::Birefringent {
                source_electrons_per_us: 1.0,
                displacement_px: 100.0,
            },
        ];
        for s in bad {
            assert!(s.validate().is_err(), "{s:?}");
        }
    }
}
