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

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use plotters::prelude::*;
use sdi_core::calibration::DarkCalibration;
use sdi_core::dark_frame::DarkAccumulator;
use sdi_core::modulation::Illumination;
use sdi_core::scene::ColourChart;
use sdi_core::scene::{SceneId, SceneSpec};
use sdi_core::sensor::{mixing_with_adc, SkellamMixing};
use sdi_core::separation::{
    auto_segment, bilateral_exact, noise_sigma, pool_moments, segment_moments, unmix,
    unmix_local_into, BilateralGrid, BilateralParams, PoolParams, SegmentParams,
    SeparableBilateral, Separated, SeparationError, UnmixOptions, Welford,
};
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::{Frame, Image};

use super::report_files::ReportFiles;
use crate::exit::CliError;
use crate::stdout::outln;

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
    #[arg(long, default_value = "ti", value_parser = super::sensor_arg::parse_sensor)]
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
struct Chosen(Vec<Estimator>);

impl Chosen {
    fn has(&self, e: Estimator) -> bool {
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

/// Running per-pixel sums of the simulator's truth over frames.
struct TruthSums {
    plus: Vec<f64>,
    minus: Vec<f64>,
    frames: usize,
}

impl TruthSums {
    fn new(pixels: usize) -> Self {
        Self {
            plus: vec![0.0; pixels],
            minus: vec![0.0; pixels],
            frames: 0,
        }
    }

    fn push(&mut self, e: &sdi_core::simulator::WellExpectation) {
        for (s, &v) in self.plus.iter_mut().zip(&e.i_plus_electrons.data) {
            *s += f64::from(v);
        }
        for (s, &v) in self.minus.iter_mut().zip(&e.i_minus_electrons.data) {
            *s += f64::from(v);
        }
        self.frames += 1;
    }

    /// The mean truth so far (exact for a static scene: N copies of an f32
    /// sum exactly in f64).
    fn mean(&self, patch: &Option<Vec<Option<usize>>>) -> Truth {
        let n = self.frames.max(1) as f64;
        Truth {
            plus: self.plus.iter().map(|s| s / n).collect(),
            minus: self.minus.iter().map(|s| s / n).collect(),
            patch: patch.clone(),
        }
    }
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
        None => run_measured(args)?,
        Some((name, scene)) => {
            run(args, &name, scene).map_err(|e| CliError::Runtime(e.to_string()))?
        }
    };
    publish(report, files, json)
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

/// Writes the files, then prints.
fn publish(report: Report, files: ReportFiles, json: bool) -> Result<(), CliError> {
    files.write("separation.tsv", tsv(&report.rows).as_bytes())?;
    if files.contains("separation.svg") {
        let mut svg = String::new();
        plot(&mut svg, &report.scene, &report.rows)
            .map_err(|e| CliError::Runtime(e.to_string()))?;
        files.write("separation.svg", svg.as_bytes())?;
    }
    let doc = json_doc(&report);
    if json {
        let text = serde_json::to_string_pretty(&doc)
            .map_err(|e| CliError::Runtime(format!("JSON: {e}")))?;
        files.write("separation.json", text.as_bytes())?;
    }
    let written = files.commit()?;
    if json {
        outln!("{doc}")?;
        return Ok(());
    }
    print_table(&report)?;
    let names: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
    outln!("wrote {}", names.join(", "))?;
    Ok(())
}

/// M1 without subtracting sigma_read^2 first (the paper's Fig. pol
/// compares both).
const NO_READ: UnmixOptions = UnmixOptions {
    subtract_read_noise: false,
    nonnegative: false,
};
/// M1 constrained to I+, I- >= 0.
const NON_NEG: UnmixOptions = UnmixOptions {
    subtract_read_noise: true,
    nonnegative: true,
};

/// Runs the report on the simulator (frames streamed, constant memory in N).
fn run(args: &SeparationReportArgs, name: &str, scene: SceneSpec) -> Result<Report, ReportError> {
    let mut sensor = args.sensor.params();
    if let Some(e) = args.exposure_us {
        sensor.exposure_us = e;
    }
    let h = mixing_with_adc(&sensor);
    let mut config = SimConfig::new(sensor.clone(), scene);
    config.seed = args.seed;
    let mut sim = Simulator::new(config)?;
    let dark_cal = dark_calibration(&mut sim)?;
    let (w, ht) = (sensor.width, sensor.height);
    let chart = (name == "colour-chart").then(|| ColourChart::new(w, ht, 1.0, 1.0));
    let patch: Option<Vec<Option<usize>>> =
        chart.map(|c| (0..w * ht).map(|i| c.patch_at(i % w, i / w)).collect());
    let chosen = Chosen(args.estimators.clone());
    let m1 = M1Run {
        h: &h,
        patch: &patch,
        n_max: args.max_frames.max(2),
        chosen: &chosen,
    };
    let (mut rows, first) = m1.rows(&mut sim, &dark_cal)?;
    // Single-frame estimators on the first frame, against its own truth.
    let (one, truth) = first.ok_or(ReportError::NoFrames)?;
    rows.extend(m2_rows(&one, &truth, &h, &chosen)?);
    rows.extend(m3_rows(&one, &truth, &h, &chosen)?);
    if rows.is_empty() {
        return Err(ReportError::NoRows);
    }
    Ok(Report {
        scene: name.to_owned(),
        model: sensor.model.clone(),
        width: w,
        height: ht,
        truth: if sim.scene_is_static() {
            "the simulator's expected wells"
        } else {
            "per frame (moving scene): M1 against the mean over its N frames, single-frame estimators against the first frame's"
        },
        truth_se: None,
        rows,
    })
}

/// 100 dark frames, averaged, to subtract before separating (section 6).
fn dark_calibration(sim: &mut Simulator) -> Result<DarkCalibration, ReportError> {
    let (w, ht) = (sim.params().width, sim.params().height);
    let dark = Illumination::dark(sim.params().modulation_hz);
    let mut frame = Frame::new(w, ht);
    let mut darks = DarkAccumulator::new(w, ht);
    for _ in 0..100 {
        sim.capture(&dark, &mut frame);
        darks
            .push(&frame)
            .map_err(|e| ReportError::Dark(e.to_string()))?;
    }
    Ok(DarkCalibration::from_accumulator(&darks)?)
}

/// The N at which M1 is read out: a few decades up to `n_max`, and `n_max`.
fn m1_checkpoints(n_max: usize) -> Vec<usize> {
    let mut ns: Vec<usize> = [10, 30, 100, 300, 1000, 3000]
        .into_iter()
        .filter(|&n| n <= n_max)
        .collect();
    if ns.last() != Some(&n_max) {
        ns.push(n_max);
    }
    ns
}

/// The first frame and its own truth, for the single-frame estimators.
type FirstFrame = (Frame, Truth);

/// M1 over N frames streamed from the simulator.
struct M1Run<'a> {
    h: &'a SkellamMixing,
    patch: &'a Option<Vec<Option<usize>>>,
    n_max: usize,
    chosen: &'a Chosen,
}

impl M1Run<'_> {
    /// M1's rows (time: per pushed frame, plus the final inversion), one
    /// accumulator read out at each checkpoint; and the first frame with
    /// its truth, for the single-frame estimators.
    fn rows(
        &self,
        sim: &mut Simulator,
        dark_cal: &DarkCalibration,
    ) -> Result<(Vec<Row>, Option<FirstFrame>), ReportError> {
        let (w, ht) = (sim.params().width, sim.params().height);
        let light = Illumination::snapshot(sim.params().modulation_hz);
        let ns = m1_checkpoints(self.n_max);
        let mut frame = Frame::new(w, ht);
        let mut acc = Welford::new(w, ht);
        let mut truths = TruthSums::new(w * ht);
        let mut push_time = Duration::ZERO;
        let mut first: Option<FirstFrame> = None;
        let mut rows = Vec::new();
        for n in 1..=self.n_max {
            sim.capture(&light, &mut frame);
            dark_cal.subtract(&mut frame)?;
            truths.push(sim.last_expectation());
            if first.is_none() {
                first = Some((frame.clone(), truths.mean(self.patch)));
            }
            let t0 = Instant::now();
            acc.push(&frame)?;
            push_time += t0.elapsed();
            if ns.contains(&n) {
                let truth = truths.mean(self.patch);
                self.rows_at(n, &acc, &truth, push_time, &mut rows)?;
            }
        }
        Ok((rows, first))
    }

    /// The rows of M1 read out after `n` frames (at `n_max` also pooled,
    /// with read:=0 and non-negative).
    fn rows_at(
        &self,
        n: usize,
        acc: &Welford,
        truth: &Truth,
        push_time: Duration,
        rows: &mut Vec<Row>,
    ) -> Result<(), ReportError> {
        let h = self.h;
        let with_read = UnmixOptions::default();
        let t0 = Instant::now();
        let m = acc.moments()?;
        let sep = unmix(&m, h, with_read)?;
        let ms = (push_time + t0.elapsed()).as_secs_f64() * 1e3 / n as f64;
        let last = n == self.n_max;
        if self.chosen.has(Estimator::M1) {
            let mut r = row("M1", format!("N={n}"), &sep, truth, ms);
            r.floor = Some(m1_floor(truth, h, n));
            rows.push(r);
        }
        if last && self.chosen.has(Estimator::M1Pooled) {
            let t0 = Instant::now();
            let pooled = pool_moments(&m, PoolParams::default())?;
            let sep = unmix(&pooled, h, with_read)?;
            let extra = t0.elapsed().as_secs_f64() * 1e3 / n as f64;
            let r = PoolParams::default().radius_px;
            let params = format!("N={n}, r={r}");
            rows.push(row("M1 pooled", params, &sep, truth, ms + extra));
        }
        if last && self.chosen.has(Estimator::M1) {
            let sep = unmix(&m, h, NO_READ)?;
            rows.push(row("M1", format!("N={n}, read:=0"), &sep, truth, ms));
            let sep = unmix(&m, h, NON_NEG)?;
            rows.push(row("M1", format!("N={n}, non-neg"), &sep, truth, ms));
        }
        Ok(())
    }
}

/// M2 (automatic segments of one frame) at a few smoothing radii.
fn m2_rows(
    one: &Frame,
    truth: &Truth,
    h: &SkellamMixing,
    chosen: &Chosen,
) -> Result<Vec<Row>, ReportError> {
    let mut rows = Vec::new();
    if !chosen.has(Estimator::M2) {
        return Ok(rows);
    }
    for radius in [1, 2, 4] {
        let p = SegmentParams {
            smooth_radius_px: radius,
            ..SegmentParams::default()
        };
        let t0 = Instant::now();
        let seg = auto_segment(one, p)?;
        let m = segment_moments(one, &seg.labels, Some(&seg.interior))?;
        let sep = unmix(&m, h, UnmixOptions::default())?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let params = format!("smooth r={radius}");
        rows.push(row("M2 auto", params, &sep, truth, ms));
    }
    Ok(rows)
}

/// M3 (local moments by a bilateral filter on one frame), each chosen
/// variant at a few domain and range scales; the range scale comes from
/// the frame itself (robust MAD), never from the truth.
fn m3_rows(
    one: &Frame,
    truth: &Truth,
    h: &SkellamMixing,
    chosen: &Chosen,
) -> Result<Vec<Row>, ReportError> {
    let with_read = UnmixOptions::default();
    let noise_dn = noise_sigma(one);
    let mut rows = Vec::new();
    for sd in [1.5, 3.0] {
        for k in [2.0, 4.0] {
            let p = BilateralParams::new(sd, k * noise_dn);
            let params = format!("sd={sd} sr={k}sigma");
            if chosen.has(Estimator::M3Exact) {
                let (sep, ms) =
                    median_of_3(|| Ok(unmix(&bilateral_exact(one, p)?, h, with_read)?))?;
                rows.push(row("M3 exact", params.clone(), &sep, truth, ms));
            }
            // The fast variants as the daemon runs them: buffers kept, f32 unmix.
            let mut out = Separated::default();
            if chosen.has(Estimator::M3Separable) {
                let mut separable = SeparableBilateral::new();
                let ((), ms) = median_of_3(|| {
                    Ok(unmix_local_into(
                        separable.compute(one, p)?,
                        h,
                        with_read,
                        &mut out,
                    )?)
                })?;
                rows.push(row("M3 separable", params.clone(), &out, truth, ms));
            }
            if chosen.has(Estimator::M3Grid) {
                let mut grid = BilateralGrid::new();
                let ((), ms) = median_of_3(|| {
                    Ok(unmix_local_into(
                        grid.compute(one, p)?,
                        h,
                        with_read,
                        &mut out,
                    )?)
                })?;
                rows.push(row("M3 grid", params.clone(), &out, truth, ms));
            }
        }
    }
    Ok(rows)
}

/// The last result of three runs and their median wall time, ms (the
/// machine is shared).
fn median_of_3<T>(
    mut run: impl FnMut() -> Result<T, ReportError>,
) -> Result<(T, f64), ReportError> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let t0 = Instant::now();
        last = Some(run()?);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let result = last.ok_or(ReportError::Plot("no run".into()))?;
    Ok((result, times[1]))
}

fn rel(est: &Image<f32>, truth: &[f64]) -> (f64, f64) {
    let n = truth.len().max(1) as f64;
    let mean_t = (truth.iter().sum::<f64>() / n).abs().max(1e-9);
    let (mut se, mut b) = (0.0, 0.0);
    for (e, t) in est.data.iter().zip(truth) {
        let d = *e as f64 - t;
        se += d * d;
        b += d;
    }
    ((se / n).sqrt() / mean_t, b / n / mean_t)
}

/// Relative RMSE over the patches of the patch means.
fn rel_patch(est: &Image<f32>, truth: &[f64], patch: &[Option<usize>]) -> Option<f64> {
    let mut acc: Vec<(f64, f64, f64)> = Vec::new();
    for (i, p) in patch.iter().enumerate() {
        if let Some(p) = *p {
            if acc.len() <= p {
                acc.resize(p + 1, (0.0, 0.0, 0.0));
            }
            acc[p].0 += est.data[i] as f64;
            acc[p].1 += truth[i];
            acc[p].2 += 1.0;
        }
    }
    let used: Vec<_> = acc.into_iter().filter(|a| a.2 > 0.0).collect();
    if used.is_empty() {
        return None;
    }
    let k = used.len() as f64;
    let se: f64 = used.iter().map(|(e, t, n)| ((e - t) / n).powi(2)).sum();
    let mt: f64 = used.iter().map(|(_, t, n)| t / n).sum::<f64>() / k;
    Some((se / k).sqrt() / mt.abs().max(1e-9))
}

/// M1's per-pixel floor from sampling alone: Var(I+-) = (Var S + Var D) / 4,
/// Var S = 2 sigma^4 / ((N - 1) g^4) (sample variance), Var D = sigma^2 / (N g^2)
/// (mean), sigma^2 = g^2 (I+ + I-) + sigma_read^2; RMS over pixels / mean truth.
fn m1_floor(t: &Truth, h: &SkellamMixing, n: usize) -> (f64, f64) {
    let g = h.gain_dn_per_electron;
    let nf = n as f64;
    let k = t.plus.len().max(1) as f64;
    let v: f64 = t
        .plus
        .iter()
        .zip(&t.minus)
        .map(|(p, m)| {
            let s2 = g * g * (p + m) + h.read_variance_dn2;
            0.25 * (2.0 * s2 * s2 / ((nf - 1.0) * g.powi(4)) + s2 / (nf * g * g))
        })
        .sum();
    let rms = (v / k).sqrt();
    let mean = |x: &[f64]| (x.iter().sum::<f64>() / k).abs().max(1e-9);
    (rms / mean(&t.plus), rms / mean(&t.minus))
}

fn row(method: &'static str, params: String, sep: &Separated, t: &Truth, ms: f64) -> Row {
    let (rmse_plus, bias_plus) = rel(&sep.i_plus_electrons, &t.plus);
    let (rmse_minus, bias_minus) = rel(&sep.i_minus_electrons, &t.minus);
    let patch = |e: &Image<f32>, tr: &[f64]| t.patch.as_ref().and_then(|p| rel_patch(e, tr, p));
    Row {
        method,
        params,
        rmse_plus,
        bias_plus,
        rmse_minus,
        bias_minus,
        patch_plus: patch(&sep.i_plus_electrons, &t.plus),
        patch_minus: patch(&sep.i_minus_electrons, &t.minus),
        floor: None,
        ms_per_frame: ms,
    }
}

fn print_table(r: &Report) -> Result<(), CliError> {
    let (scene, model, w, h, rows) = (&r.scene, &r.model, r.width, r.height, &r.rows);
    outln!("separation report: scene {scene}, {w}x{h}, sensor {model}, dark-frame subtracted")?;
    outln!("truth: {}", r.truth)?;
    if let Some((p, m)) = r.truth_se {
        outln!(
            "the truth's own sampling error (relative RMS standard error): I+ {:.2}%, I- {:.2}%",
            100.0 * p,
            100.0 * m
        )?;
    }
    outln!("relative RMSE per pixel (rmse), per patch mean (patch), M1's sampling floor per pixel (floor)")?;
    outln!(
        "{:<13} {:<22} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>15} {:>10}",
        "method",
        "params",
        "rmse I+",
        "bias I+",
        "rmse I-",
        "bias I-",
        "patch I+",
        "patch I-",
        "floor I+/I-",
        "ms/frame"
    )?;
    let pct = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.2}%", 100.0 * v));
    for r in rows {
        let floor = r.floor.map_or("-".to_string(), |(a, b)| {
            format!("{:.2}/{:.2}%", 100.0 * a, 100.0 * b)
        });
        outln!(
            "{:<13} {:<22} {:>8.2}% {:>+8.2}% {:>8.2}% {:>+8.2}% {:>9} {:>9} {:>15} {:>10.3}",
            r.method,
            r.params,
            100.0 * r.rmse_plus,
            100.0 * r.bias_plus,
            100.0 * r.rmse_minus,
            100.0 * r.bias_minus,
            pct(r.patch_plus),
            pct(r.patch_minus),
            floor,
            r.ms_per_frame
        )?;
    }
    outln!("{}", ordering(rows))?;
    Ok(())
}

/// The paper's ordering M1 < M2 < M3: best M1 (largest N, plain), best M2
/// auto, best M3 (any variant), compared on the sum of the I+ and I- errors,
/// per patch when available, else per pixel.
pub fn ordering(rows: &[Row]) -> String {
    let err = |r: &Row| match (r.patch_plus, r.patch_minus) {
        (Some(a), Some(b)) => a + b,
        _ => r.rmse_plus + r.rmse_minus,
    };
    let best = |pred: &dyn Fn(&Row) -> bool| {
        rows.iter()
            .filter(|r| pred(r))
            .map(err)
            .fold(f64::INFINITY, f64::min)
    };
    let m1 = rows
        .iter()
        .rfind(|r| r.method == "M1" && !r.params.contains(','))
        .map_or(f64::INFINITY, err);
    let m2 = best(&|r| r.method == "M2 auto");
    let m3 = best(&|r| r.method.starts_with("M3"));
    let basis = if rows.iter().any(|r| r.patch_plus.is_some()) {
        "per patch"
    } else {
        "per pixel"
    };
    if [m1, m2, m3].iter().any(|e| !e.is_finite()) {
        return format!("ordering ({basis}): not all of M1, M2 auto and M3 ran");
    }
    format!(
        "ordering ({basis}, I+ + I- error): M1 {:.2}% < M2 auto {:.2}% < M3 {:.2}%: {}",
        100.0 * m1,
        100.0 * m2,
        100.0 * m3,
        if m1 < m2 && m2 < m3 {
            "holds"
        } else {
            "does NOT hold"
        }
    )
}

/// The report as JSON (separation.json, and stdout with `--json`).
fn json_doc(report: &Report) -> serde_json::Value {
    let rows = &report.rows;
    let order = ordering(rows);
    let rows: Vec<serde_json::Value> = rows
        .iter()
        .map(|r| {
            serde_json::json!({
                "method": r.method,
                "params": r.params,
                "rel_rmse_plus": r.rmse_plus,
                "rel_bias_plus": r.bias_plus,
                "rel_rmse_minus": r.rmse_minus,
                "rel_bias_minus": r.bias_minus,
                "patch_rmse_plus": r.patch_plus,
                "patch_rmse_minus": r.patch_minus,
                "floor_plus": r.floor.map(|f| f.0),
                "floor_minus": r.floor.map(|f| f.1),
                "ms_per_frame": r.ms_per_frame,
            })
        })
        .collect();
    serde_json::json!({
        "scene": report.scene,
        "sensor": report.model,
        "width": report.width,
        "height": report.height,
        "truth": report.truth,
        "truth_rel_se_plus": report.truth_se.map(|t| t.0),
        "truth_rel_se_minus": report.truth_se.map(|t| t.1),
        "ordering": order,
        "rows": rows,
    })
}

fn tsv(rows: &[Row]) -> String {
    let mut s = String::from("method\tparams\trel_rmse_plus\trel_bias_plus\trel_rmse_minus\trel_bias_minus\tpatch_rmse_plus\tpatch_rmse_minus\tfloor_plus\tfloor_minus\tms_per_frame\n");
    let opt = |v: Option<f64>| v.map_or("NA".to_string(), |v| format!("{v:.6}"));
    for r in rows {
        s += &format!(
            "{}\t{}\t{:.6}\t{:.6}\t{:.6}\t{:.6}\t{}\t{}\t{}\t{}\t{:.4}\n",
            r.method,
            r.params,
            r.rmse_plus,
            r.bias_plus,
            r.rmse_minus,
            r.bias_minus,
            opt(r.patch_plus),
            opt(r.patch_minus),
            opt(r.floor.map(|f| f.0)),
            opt(r.floor.map(|f| f.1)),
            r.ms_per_frame
        );
    }
    s
}

/// Error (mean of the I+ and I- relative RMSE) against time per frame, log-log.
fn plot(svg: &mut String, scene: &str, rows: &[Row]) -> Result<(), ReportError> {
    let err = |r: &Row| 0.5 * (r.rmse_plus + r.rmse_minus);
    let pe = |e: DrawingAreaErrorKind<_>| ReportError::Plot(e.to_string());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for r in rows {
        x0 = x0.min(r.ms_per_frame);
        x1 = x1.max(r.ms_per_frame);
        y0 = y0.min(err(r));
        y1 = y1.max(err(r));
    }
    let (x0, x1) = ((x0 * 0.5).max(1e-4), (x1 * 2.0).max(1e-3));
    let (y0, y1) = ((y0 * 0.5).max(1e-4), (y1 * 2.0).max(1e-3));
    let root = SVGBackend::with_string(svg, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("SDI separation on {scene}: error vs run time"),
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(pe)?;
    chart
        .configure_mesh()
        .x_desc("time per frame, ms")
        .y_desc("relative RMSE, mean of I+ and I-")
        .draw()
        .map_err(pe)?;
    let series: [(&str, &str, RGBColor); 8] = [
        ("M1", "", BLUE),
        ("M1", "read:=0", RGBColor(120, 120, 255)),
        ("M1", "non-neg", RGBColor(0, 160, 160)),
        ("M1 pooled", "r=", RGBColor(0, 0, 90)),
        ("M2 auto", "", GREEN),
        ("M3 exact", "", RED),
        ("M3 separable", "", RGBColor(230, 130, 0)),
        ("M3 grid", "", RGBColor(160, 0, 160)),
    ];
    for (method, tag, colour) in series {
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| {
                r.method == method
                    && (tag.is_empty() && !r.params.contains(',')
                        || !tag.is_empty() && r.params.contains(tag))
            })
            .map(|r| (r.ms_per_frame.max(x0), err(r)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let label = if tag.is_empty() {
            method.to_string()
        } else {
            format!("{method} ({tag})")
        };
        chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(pe)?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 4, colour.filled())))
            .map_err(pe)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(pe)?;
    root.present().map_err(pe)?;
    Ok(())
}

/// Which light source a truth input shows alone. In a recording made in
/// two-shot mode the even-numbered frames are LS1 alone and the odd LS2
/// alone (`ModeId::illumination`); only those of the source asked for are
/// used. Frames of any other mode, and `.npy` frames, are all used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Alone {
    Ls1,
    Ls2,
}

impl Alone {
    fn takes(self, mode: Option<&str>, sequence: u64) -> bool {
        mode != Some("two-shot") || (sequence & 1 == 0) == (self == Alone::Ls1)
    }
}

/// Streams up to `max` frames of a recording or .npy (dark subtracted as
/// recorded) through `each` (with `alone`, only the frames of that source
/// when the recording is two-shot); the number of frames and the input's
/// description.
fn stream_frames(
    path: &Path,
    max: usize,
    alone: Option<Alone>,
    mut each: impl FnMut(&Frame) -> Result<(), CliError>,
) -> Result<(usize, super::frames::InputInfo), CliError> {
    let (mut input, info) = super::frames::FrameInput::open(path)?;
    let mut frame = Frame::new(info.width, info.height);
    let mut n = 0;
    while n < max && input.next_frame(path, &mut frame)? {
        if alone.is_some_and(|a| !a.takes(input.last_mode(), frame.sequence)) {
            continue;
        }
        each(&frame)?;
        n += 1;
    }
    if n == 0 {
        return Err(CliError::Usage(format!(
            "'{}' holds no frames",
            path.display()
        )));
    }
    Ok((n, info))
}

/// The per-pixel mean and its sampling variance (sample variance / frames,
/// 0 below two samples), DN and DN^2, and the frame size.
struct MeanDn {
    mean: Vec<f64>,
    var_of_mean: Vec<f64>,
    width: usize,
    height: usize,
}

/// Per-pixel mean over up to `max` frames (unusable samples skipped).
fn mean_dn(path: &Path, max: usize, alone: Alone) -> Result<MeanDn, CliError> {
    let (mut s, mut q, mut k) = (Vec::new(), Vec::new(), Vec::new());
    let (_, info) = stream_frames(path, max, Some(alone), |f| {
        let n = f.dn.data.len();
        if s.is_empty() {
            (s, q, k) = (vec![0.0; n], vec![0.0; n], vec![0u32; n]);
        }
        for i in 0..n {
            let v = f.dn.data[i];
            if v.is_finite() && f.saturated.data[i] == 0 {
                s[i] += f64::from(v);
                q[i] += f64::from(v) * f64::from(v);
                k[i] += 1;
            }
        }
        Ok(())
    })?;
    let mean: Vec<f64> = s
        .iter()
        .zip(&k)
        .map(|(s, &k)| if k > 0 { s / f64::from(k) } else { 0.0 })
        .collect();
    let var_of_mean = q
        .iter()
        .zip(&mean)
        .zip(&k)
        .map(|((q, m), &k)| {
            let k = f64::from(k);
            if k >= 2.0 {
                ((q - k * m * m) / (k - 1.0)).max(0.0) / k
            } else {
                0.0
            }
        })
        .collect();
    Ok(MeanDn {
        mean,
        var_of_mean,
        width: info.width,
        height: info.height,
    })
}

/// RMS over pixels of the standard error of a measured truth, relative to
/// its mean (`var_dn2`: per-pixel variance of the mean, DN^2; `g`: DN per
/// electron): the error any estimator shows against it from the truth alone.
fn truth_rel_se(var_dn2: &[f64], truth: &[f64], g: f64) -> f64 {
    let k = truth.len().max(1) as f64;
    let rms_e = (var_dn2.iter().sum::<f64>() / k).sqrt() / g;
    rms_e / (truth.iter().sum::<f64>() / k).abs().max(1e-9)
}

/// `report separation` on measured data: the truth is the mean of the
/// LS1-only and LS2-only frames through g (I+ = mean / g, I- = -mean / g,
/// or +mean / g when LS2 was driven in phase);
/// M1 over N frames, pooled M1, M2 auto and M3 (separable, range scale from
/// the frame) on the both-sources frames. Every input streams (constant
/// memory in N).
fn run_measured(args: &SeparationReportArgs) -> Result<Report, CliError> {
    let (Some(input), Some(tp), Some(tm)) = (&args.input, &args.truth_plus, &args.truth_minus)
    else {
        return Err(CliError::Usage(
            "--in needs --truth-plus and --truth-minus".into(),
        ));
    };
    let n_max = args.max_frames.clamp(2, MAX_REPORT_FRAMES);
    let plus = mean_dn(tp, n_max, Alone::Ls1)?;
    let minus = mean_dn(tm, n_max, Alone::Ls2)?;
    let both = BothSources::stream(input, n_max)?;
    let (w, ht) = (both.info.width, both.info.height);
    if (plus.width, plus.height) != (w, ht) || (minus.width, minus.height) != (w, ht) {
        return Err(CliError::Usage(
            "the truth frames differ in size from --in".into(),
        ));
    }
    // A recording's own sensor wins; an .npy uses --sensor.
    let sensor = both.info.sensor.is_none().then_some(&args.sensor);
    let h = super::separate::choose_mixing(None, sensor, &both.info)?.h;
    let (truth, truth_se) = measured_truth(&plus, &minus, h.gain_dn_per_electron);
    let chosen = Chosen(args.estimators.clone());
    let mut rows = both.m1_rows(&truth, &h, &chosen)?;
    rows.extend(both.single_frame_rows(&truth, &h, &chosen)?);
    if rows.is_empty() {
        return Err(CliError::Usage(ReportError::NoRows.to_string()));
    }
    Ok(Report {
        scene: format!("measured {}", input.display()),
        model: "measured".into(),
        width: w,
        height: ht,
        truth: "the mean of the LS1-only and LS2-only frames through g",
        truth_se: Some(truth_se),
        rows,
    })
}

/// A measured-data report's estimator error: a usage error (the input
/// does not suit the estimator).
fn usage(e: SeparationError) -> CliError {
    CliError::Usage(e.to_string())
}

/// The truth from the LS1-only and LS2-only means through `g` (DN per
/// electron), and its relative standard error (I+, I-).
fn measured_truth(plus: &MeanDn, minus: &MeanDn, g: f64) -> (Truth, (f64, f64)) {
    // LS2 alone lands in I- (negative D) when driven out of phase, as in the
    // snapshot; two-shot's B frames drive it in phase (positive D). The
    // pooled sign tells which.
    let sign = if minus.mean.iter().sum::<f64>() > 0.0 {
        eprintln!("note: --truth-minus frames are positive (LS2 driven in phase, as two-shot's B frames): I- = +mean / g");
        1.0
    } else {
        -1.0
    };
    let truth = Truth {
        plus: plus.mean.iter().map(|m| m / g).collect(),
        minus: minus.mean.iter().map(|m| sign * m / g).collect(),
        patch: None,
    };
    let truth_se = (
        truth_rel_se(&plus.var_of_mean, &truth.plus, g),
        truth_rel_se(&minus.var_of_mean, &truth.minus, g),
    );
    (truth, truth_se)
}

/// The both-sources frames of measured data, streamed once: M1's
/// accumulator (timed per push) and the first frame, kept for the
/// single-frame estimators.
struct BothSources {
    frames: usize,
    info: super::frames::InputInfo,
    acc: Welford,
    first: Frame,
    push_time: Duration,
}

impl BothSources {
    fn stream(input: &Path, n_max: usize) -> Result<Self, CliError> {
        let mut acc: Option<Welford> = None;
        let mut first: Option<Frame> = None;
        let mut push_time = Duration::ZERO;
        let (frames, info) = stream_frames(input, n_max, None, |f| {
            let a = acc.get_or_insert_with(|| Welford::new(f.width(), f.height()));
            let t0 = Instant::now();
            a.push(f).map_err(usage)?;
            push_time += t0.elapsed();
            first.get_or_insert_with(|| f.clone());
            Ok(())
        })?;
        let (Some(acc), Some(first)) = (acc, first) else {
            return Err(CliError::Usage(format!(
                "'{}' holds no frames",
                input.display()
            )));
        };
        Ok(Self {
            frames,
            info,
            acc,
            first,
            push_time,
        })
    }

    /// M1 and pooled M1 over every frame (two at least).
    fn m1_rows(
        &self,
        truth: &Truth,
        h: &SkellamMixing,
        chosen: &Chosen,
    ) -> Result<Vec<Row>, CliError> {
        let (n, opts) = (self.frames, UnmixOptions::default());
        let mut rows = Vec::new();
        if n < 2 {
            return Ok(rows);
        }
        let t0 = Instant::now();
        let m = self.acc.moments().map_err(usage)?;
        let sep = unmix(&m, h, opts).map_err(usage)?;
        let ms = (self.push_time + t0.elapsed()).as_secs_f64() * 1e3 / n as f64;
        if chosen.has(Estimator::M1) {
            let mut r = row("M1", format!("N={n}"), &sep, truth, ms);
            r.floor = Some(m1_floor(truth, h, n));
            rows.push(r);
        }
        if chosen.has(Estimator::M1Pooled) {
            let pooled = pool_moments(&m, PoolParams::default()).map_err(usage)?;
            let sep = unmix(&pooled, h, opts).map_err(usage)?;
            rows.push(row("M1 pooled", format!("N={n}"), &sep, truth, ms));
        }
        Ok(rows)
    }

    /// M2 auto and M3 separable (range scale from the frame) on the first frame.
    fn single_frame_rows(
        &self,
        truth: &Truth,
        h: &SkellamMixing,
        chosen: &Chosen,
    ) -> Result<Vec<Row>, CliError> {
        let (one, opts) = (&self.first, UnmixOptions::default());
        let mut rows = Vec::new();
        if chosen.has(Estimator::M2) {
            let t0 = Instant::now();
            let seg = auto_segment(one, SegmentParams::default()).map_err(usage)?;
            let m = segment_moments(one, &seg.labels, Some(&seg.interior)).map_err(usage)?;
            let sep = unmix(&m, h, opts).map_err(usage)?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            rows.push(row("M2 auto", "smooth r=2".into(), &sep, truth, ms));
        }
        if !chosen.has(Estimator::M3Separable) {
            return Ok(rows);
        }
        let noise = noise_sigma(one);
        for k in [2.0, 4.0] {
            let p = BilateralParams::new(1.5, k * noise);
            let mut out = Separated::default();
            let mut separable = SeparableBilateral::new();
            let t0 = Instant::now();
            let local = separable.compute(one, p).map_err(usage)?;
            unmix_local_into(local, h, opts, &mut out).map_err(usage)?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let params = format!("sd=1.5 sr={k}sigma");
            rows.push(row("M3 separable", params, &out, truth, ms));
        }
        Ok(rows)
    }
}
