//! The arguments: scene or measured inputs, the estimators, the frames.

use std::path::PathBuf;

use sdi_core::scene::SceneId;

/// Most frames `--max-frames` accepts: M1's error at 100,000 frames is far
/// below the simulator's own model error, and the run takes hours.
pub const MAX_REPORT_FRAMES: usize = 100_000;

/// Arguments of `sdictl report separation`.
#[derive(Debug, Clone, clap::Args)]
pub struct SeparationReportArgs {
    /// Simulator scene.
    #[arg(long, default_value = "colour-chart",
        value_parser = sdi_config::cli::choice::<SceneId>())]
    pub scene: SceneId,
    /// A scene parameter, KEY=VALUE (repeatable; as `sdictl sim --scene-param`).
    #[arg(
        long = "scene-param",
        value_name = "KEY=VALUE",
        conflicts_with = "input"
    )]
    pub scene_params: Vec<String>,
    /// Directory for the plot (separation.svg) and the table (separation.tsv).
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
    /// Largest N for M1 (2..=100000: M1 needs two frames for a variance).
    #[arg(long, visible_alias = "frames", default_value_t = 1000, value_parser = parse_max_frames, allow_negative_numbers = true)]
    pub max_frames: usize,
    /// Estimators to run, comma-separated [default: all].
    #[arg(long, value_enum, value_delimiter = ',', num_args = 1..)]
    pub estimators: Vec<Estimator>,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sensor: preset (ti, pmd) or a sensor description file (TOML).
    #[arg(long, default_value = "ti", value_parser = crate::offline::sensor_arg::parse_sensor)]
    pub sensor: sdi_core::sensor::SensorDescription,
    /// Exposure per frame, microseconds [default: the sensor's].
    #[arg(long, value_parser = parse_exposure_us)]
    pub exposure_us: Option<f64>,
    /// Measured data instead of the simulator: frames with both sources on
    /// (.sdirec or .npy, DN, dark-subtracted); needs --truth-plus and --truth-minus.
    #[arg(long = "in", requires_all = ["truth_plus", "truth_minus"])]
    pub input: Option<PathBuf>,
    /// Frames with LS1 alone: I+ = mean / g (eq. pixeleff). A recording
    /// made in two-shot mode gives its LS1-only (even-numbered) frames.
    #[arg(long, requires = "input")]
    pub truth_plus: Option<PathBuf>,
    /// Frames with LS2 alone: I- = -mean / g. A recording made in two-shot
    /// mode gives its LS2-only (odd-numbered) frames.
    #[arg(long, requires = "input")]
    pub truth_minus: Option<PathBuf>,
}

/// An estimator (family) of the report; `m3` stands for its three variants.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Estimator {
    /// M1 over N frames (plain, and with read:=0 and non-negative at the largest N).
    M1,
    /// M1 with edge-aware pooling of the moments, at the largest N.
    M1Pooled,
    /// M2: automatic segments of one frame.
    M2,
    /// M3: every bilateral variant below.
    M3,
    M3Exact,
    M3Separable,
    M3Grid,
}

/// Which estimators a report runs (empty list: all).
#[derive(Debug, Clone)]
pub(super) struct Chosen(pub(super) Vec<Estimator>);

impl Chosen {
    pub(super) fn has(&self, e: Estimator) -> bool {
        let m3 = matches!(
            e,
            Estimator::M3Exact | Estimator::M3Separable | Estimator::M3Grid
        );
        self.0.is_empty() || self.0.contains(&e) || (m3 && self.0.contains(&Estimator::M3))
    }
}

fn parse_max_frames(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (2..=MAX_REPORT_FRAMES).contains(&n) => Ok(n),
        _ => Err(format!(
            "expected a whole number from 2 to {MAX_REPORT_FRAMES} (M1 needs at least 2 frames for a variance)"
        )),
    }
}

fn parse_exposure_us(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1e6 => Ok(v),
        _ => Err("expected microseconds, 0 < X <= 1000000".into()),
    }
}
