//! `sdictl report separation`: every separation estimator over its parameter
//! range on simulator data with known ground truth; prints a table (method,
//! parameters, relative RMSE and bias of I+ and I- per pixel, relative RMSE
//! per patch on the colour chart, M1's predicted per-pixel floor, time per
//! frame) and writes the same as an SVG plot of error against run time.
//!
//! Relative RMSE per pixel = sqrt(mean over pixels (est - truth)^2) / mean
//! truth; per patch, the same over the 24 patch means (estimate averaged over
//! each patch against the truth averaged over it).
//!
//! The truth is per frame (the simulator's expected wells behind each
//! capture): M1 over N frames is compared with the mean of its N frames'
//! truths, the single-frame estimators with the first frame's, so a moving
//! scene (fan-pellets) is measured against what was in front of the sensor.
//! Frames stream through one buffer (running sums, Welford): memory does not
//! grow with `--max-frames`. The files are written before anything is
//! printed, and `--json` prints the same document as separation.json.
//!
//! One file per step: `args`, the run on the simulator (`simulated`) or on
//! measured data (`measured`), the single-frame estimators
//! (`single_frame`), the error measures (`metrics`), the outputs
//! (`publish`, `plot`).

mod args;
mod measured;
mod metrics;
mod plot;
mod publish;
mod simulated;
mod single_frame;

use sdi_core::scene::SceneSpec;
use sdi_core::separation::SeparationError;

use super::report_files::ReportFiles;
use crate::exit::CliError;

pub use args::SeparationReportArgs;

/// What can go wrong while reporting.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("simulator: {0}")]
    Simulator(#[from] sdi_core::sensor::ParamError),
    #[error("separation: {0}")]
    Separation(#[from] SeparationError),
    #[error("calibration: {0}")]
    Calibration(#[from] sdi_core::calibration::CalibrationError),
    #[error("plot: {0}")]
    Plot(String),
    #[error("dark frame: {0}")]
    Dark(String),
    #[error("the simulator produced no frame")]
    NoFrames,
    #[error(
        "none of the chosen estimators runs here (measured data: m1, m1-pooled, m2, m3-separable)"
    )]
    NoRows,
}

/// One table row.
#[derive(Debug, Clone)]
pub struct Row {
    pub method: &'static str,
    pub params: String,
    pub rmse_plus: f64,
    pub bias_plus: f64,
    pub rmse_minus: f64,
    pub bias_minus: f64,
    /// Relative RMSE of the patch means (colour chart only).
    pub patch_plus: Option<f64>,
    pub patch_minus: Option<f64>,
    /// Predicted per-pixel relative RMSE from sampling alone (M1 only).
    pub floor: Option<(f64, f64)>,
    pub ms_per_frame: f64,
}

struct Truth {
    plus: Vec<f64>,
    minus: Vec<f64>,
    /// Patch index of each pixel (colour chart), for per-patch errors.
    patch: Option<Vec<Option<usize>>>,
}

/// What a report found, before it is written or printed.
struct Report {
    scene: String,
    model: String,
    width: usize,
    height: usize,
    /// How the truth was taken, for the table's header.
    truth: &'static str,
    /// A measured truth's own sampling error (I+, I-): relative RMS over
    /// pixels of its standard error. An estimator's error against it is
    /// about sqrt(error^2 + this^2).
    truth_se: Option<(f64, f64)>,
    rows: Vec<Row>,
}

/// The subcommand: checks the arguments and creates the output files,
/// computes, writes the files, then prints (the table, or with `json` the
/// JSON document). Bad scene parameters are usage errors, the rest runtime errors.
pub fn run_cli(args: &SeparationReportArgs, json: bool) -> Result<(), CliError> {
    let scene = match args.input {
        Some(_) => None,
        None => Some(scene_of(args)?),
    };
    let mut names = vec!["separation.tsv"];
    // Measured data has no plot.
    if scene.is_some() {
        names.push("separation.svg");
    }
    if json {
        names.push("separation.json");
    }
    let files = ReportFiles::create(&args.out, &names)?;
    let report = match scene {
        None => measured::run_measured(args)?,
        Some((name, scene)) => {
            simulated::run(args, &name, scene).map_err(|e| CliError::Runtime(e.to_string()))?
        }
    };
    publish::publish(report, files, json)
}

/// The scene `--scene` names, with its `--scene-param`s.
fn scene_of(args: &SeparationReportArgs) -> Result<(String, SceneSpec), CliError> {
    let scene = args
        .scene
        .spec()
        .with_params(&args.scene_params)
        .map_err(|e| CliError::Usage(e.to_string()))?;
    Ok((args.scene.name().to_owned(), scene))
}
