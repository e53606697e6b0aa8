//! `sdictl report noise`: the paper's quantitative noise analysis (section
//! 5.5, Fig. exp_variance) on the simulator: per-pixel temporal variance
//! against intensity for the snapshot difference and the two-shot difference
//! (LS1-only frame minus LS2-only frame), straight-line fits with standard
//! errors, and the ratio of the low-light intercepts (read noise counted once
//! against twice: about 2; paper 1.97 PMD, 1.99 +- 0.37 TI). Writes
//! noise.tsv and noise.svg; the last line printed states the ratio.
//!
//! On recordings (`--in SNAPSHOT --two-shot TWO`, one static scene): each
//! pixel's temporal variance in the snapshot frames and in the differences
//! of two-shot's frame pairs (LS1-only frame n, n even, minus LS2-only frame
//! n + 1), against its intensity I = (mean A + mean B) / g from the two-shot
//! frames; pixels binned by I into `--levels` groups of equal size.

use std::path::{Path, PathBuf};

use clap::Args;
use plotters::prelude::*;
use sdi_core::calibration::{linear_fit, ratio_with_se, LinearFit};
use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorDescription;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

use super::report_files::ReportFiles;
use crate::exit::CliError;
use crate::stdout::outln;

#[derive(Debug, Args)]
pub struct NoiseReportArgs {
    /// Sensor: preset (ti, pmd) or a sensor description file (TOML).
    #[arg(long, default_value = "ti", value_parser = super::sensor_arg::parse_sensor)]
    pub sensor: SensorDescription,
    /// Directory for noise.svg and noise.tsv.
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
    /// Frames (snapshot) and frame pairs (two-shot) per intensity level (3..=10000).
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u32).range(3..=10_000))]
    pub frames: u32,
    /// Intensity levels, dark included (3..=64).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(3..=64))]
    pub levels: u32,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Measured data instead of the simulator: snapshot frames of a static
    /// scene (.sdirec, or .npy in DN, dark-subtracted); needs --two-shot.
    #[arg(long = "in", requires = "two_shot")]
    pub input: Option<PathBuf>,
    /// Two-shot frames of the same scene: a recording made in two-shot mode
    /// (even-numbered frames LS1 alone, odd LS2 alone), or an .npy whose
    /// even frames are LS1 alone and odd LS2 alone.
    #[arg(long, requires = "input")]
    pub two_shot: Option<PathBuf>,
}

/// Per-pixel running sums of one scheme's differences.
struct PixelSums {
    sum: Vec<f64>,
    sum2: Vec<f64>,
    bad: Vec<bool>,
    n: usize,
}

impl PixelSums {
    fn new(px: usize) -> Self {
        Self {
            sum: vec![0.0; px],
            sum2: vec![0.0; px],
            bad: vec![false; px],
            n: 0,
        }
    }

    /// Adds `a - b` (or `a` alone) per pixel; saturated or non-finite
    /// samples mark the pixel unusable.
    fn push(&mut self, a: &Frame, b: Option<&Frame>) {
        for i in 0..self.sum.len() {
            let (mut v, mut sat) = (f64::from(a.dn.data[i]), a.saturated.data[i] != 0);
            if let Some(b) = b {
                v -= f64::from(b.dn.data[i]);
                sat |= b.saturated.data[i] != 0;
            }
            self.bad[i] |= sat || !v.is_finite();
            self.sum[i] += v;
            self.sum2[i] += v * v;
        }
        self.n += 1;
    }

    fn variance(&self, i: usize) -> Option<f64> {
        let n = self.n as f64;
        (self.n >= 2 && !self.bad[i])
            .then(|| ((self.sum2[i] - self.sum[i] * self.sum[i] / n) / (n - 1.0)).max(0.0))
    }

    fn mean(&self, i: usize) -> Option<f64> {
        (self.n >= 1 && !self.bad[i]).then(|| self.sum[i] / self.n as f64)
    }
}

/// What a measured noise analysis found: the two series, the sensor behind
/// the data and the frames used.
struct Measured {
    snap: Series,
    two: Series,
    sensor: sdi_core::sensor::SensorParams,
    width: usize,
    height: usize,
    frames: usize,
}

fn usage(path: &Path, why: impl std::fmt::Display) -> CliError {
    CliError::Usage(format!("'{}': {why}", path.display()))
}

/// The noise analysis of recordings (or .npy stacks): see the module doc.
fn measure(
    snap_path: &Path,
    two_path: &Path,
    sensor_arg: &SensorDescription,
    levels: usize,
) -> Result<Measured, CliError> {
    use super::frames::FrameInput;
    let (mut input, info) = FrameInput::open(snap_path)?;
    let px = info.width * info.height;
    let mut frame = Frame::new(info.width, info.height);
    let mut snap = PixelSums::new(px);
    while input.next_frame(snap_path, &mut frame)? {
        snap.push(&frame, None);
    }
    let (mut input, tinfo) = FrameInput::open(two_path)?;
    if (tinfo.width, tinfo.height) != (info.width, info.height) {
        return Err(usage(two_path, "frames differ in size from --in"));
    }
    let (mut a_sums, mut b_sums, mut diffs) =
        (PixelSums::new(px), PixelSums::new(px), PixelSums::new(px));
    let mut a_frame: Option<Frame> = None;
    while input.next_frame(two_path, &mut frame)? {
        if input.last_mode().is_some_and(|m| m != "two-shot") {
            return Err(usage(
                two_path,
                "holds frames not recorded in two-shot mode (sdictl set-mode two-shot before recording)",
            ));
        }
        if frame.sequence & 1 == 0 {
            a_sums.push(&frame, None);
            a_frame = Some(frame.clone());
        } else {
            b_sums.push(&frame, None);
            // A pair: the LS1-only frame just before this LS2-only one.
            if let Some(a) = a_frame.take().filter(|a| a.sequence + 1 == frame.sequence) {
                diffs.push(&a, Some(&frame));
            }
        }
    }
    if snap.n < 2 || diffs.n < 2 {
        return Err(CliError::Usage(format!(
            "need at least 2 snapshot frames and 2 two-shot pairs; got {} and {}",
            snap.n, diffs.n
        )));
    }
    // A recording's own sensor gives g; an .npy uses --sensor.
    let sensor = info
        .sensor
        .clone()
        .or(tinfo.sensor.clone())
        .unwrap_or_else(|| sensor_arg.params());
    let g = sensor.gain_dn_per_electron();
    if !(g.is_finite() && g > 0.0) {
        return Err(CliError::Usage(format!(
            "gain rho*eta = {g} DN/electron: intensities cannot be had in electrons"
        )));
    }
    // (I, snapshot variance, two-shot variance) of every usable pixel.
    let mut pixels: Vec<(f64, f64, f64)> = (0..px)
        .filter_map(|i| {
            let x = (a_sums.mean(i)? + b_sums.mean(i)?) / g;
            Some((x, snap.variance(i)?, diffs.variance(i)?))
        })
        .filter(|p| p.0.is_finite() && p.1.is_finite() && p.2.is_finite())
        .collect();
    if pixels.len() < levels {
        return Err(CliError::Usage(format!(
            "only {} usable pixels for {levels} levels",
            pixels.len()
        )));
    }
    pixels.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut s, mut t) = (Series::default(), Series::default());
    for k in 0..levels {
        let bin = &pixels[k * pixels.len() / levels..(k + 1) * pixels.len() / levels];
        let m = bin.len() as f64;
        let x = bin.iter().map(|p| p.0).sum::<f64>() / m;
        s.electrons.push(x);
        s.variance_dn2
            .push(bin.iter().map(|p| p.1).sum::<f64>() / m);
        t.electrons.push(x);
        t.variance_dn2
            .push(bin.iter().map(|p| p.2).sum::<f64>() / m);
    }
    Ok(Measured {
        snap: s,
        two: t,
        sensor,
        width: info.width,
        height: info.height,
        frames: snap.n.min(diffs.n),
    })
}

/// Variance against intensity of one capture scheme.
#[derive(Debug, Clone, Default)]
struct Series {
    electrons: Vec<f64>,
    variance_dn2: Vec<f64>,
}

/// Mean over unsaturated pixels of the per-pixel sample variance of `diffs`.
fn mean_pixel_variance(sum: &[f64], sum2: &[f64], bad: &[bool], n: f64) -> Option<f64> {
    let mut acc = 0.0;
    let mut k = 0usize;
    for i in 0..sum.len() {
        if !bad[i] {
            acc += ((sum2[i] - sum[i] * sum[i] / n) / (n - 1.0)).max(0.0);
            k += 1;
        }
    }
    (k > 0).then(|| acc / k as f64)
}

fn wells_total(sim: &Simulator) -> f64 {
    let e = sim.last_expectation();
    let n = e.i_plus_electrons.data.len().max(1) as f64;
    e.i_plus_electrons
        .data
        .iter()
        .zip(&e.i_minus_electrons.data)
        .map(|(a, b)| f64::from(*a) + f64::from(*b))
        .sum::<f64>()
        / n
}

/// Runs the simulation and the fits.
/// With `json`, the summary on stdout is one JSON object.
pub fn run(args: &NoiseReportArgs, json: bool) -> Result<(), CliError> {
    let t0 = std::time::Instant::now();
    let files = ReportFiles::create(&args.out, &["noise.tsv", "noise.svg"])?;
    let (snap, two, sensor, n, levels, source) = match (&args.input, &args.two_shot) {
        (Some(i), Some(t)) => {
            let m = measure(i, t, &args.sensor, args.levels as usize)?;
            let mut sensor = m.sensor;
            (sensor.width, sensor.height) = (m.width, m.height);
            let source = format!("recordings {} and {}", i.display(), t.display());
            (
                m.snap,
                m.two,
                sensor,
                m.frames,
                args.levels as usize,
                source,
            )
        }
        _ => {
            let (snap, two, sensor) = simulate(args)?;
            let source = "simulator".to_string();
            (
                snap,
                two,
                sensor,
                args.frames as usize,
                args.levels as usize,
                source,
            )
        }
    };
    finish(files, json, t0, (snap, two, sensor, n, levels, source))
}

/// The two series on the simulator: flat fields at `--levels` intensities.
fn simulate(
    args: &NoiseReportArgs,
) -> Result<(Series, Series, sdi_core::sensor::SensorParams), CliError> {
    let mut sensor = args.sensor.params();
    // Noise statistics do not depend on the frame size: a small frame is enough.
    sensor.width = sensor.width.min(64);
    sensor.height = sensor.height.min(48);
    let hz = sensor.modulation_hz;
    let n = args.frames as usize;
    let px = sensor.width * sensor.height;
    // Brightest level keeps each well below a third of full well.
    let max_rate = sensor.full_well_electrons / 3.0 / sensor.exposure_us;
    let levels = args.levels as usize;
    let mut snap = Series::default();
    let mut two = Series::default();
    let mut frame = Frame::new(sensor.width, sensor.height);
    let mut b_frame = Frame::new(sensor.width, sensor.height);
    for k in 0..levels {
        let rate = if k == 0 {
            0.0
        } else {
            max_rate * 200f64.powf((k as f64 - (levels - 1) as f64) / (levels - 1) as f64)
        };
        let scene = SceneSpec::FlatField {
            ls1_electrons_per_us: rate,
            ls2_electrons_per_us: rate,
        };
        let mut config = SimConfig::new(sensor.clone(), scene);
        config.seed = args.seed.wrapping_add(k as u64);
        let mut sim = Simulator::new(config).map_err(|e| CliError::Usage(e.to_string()))?;
        // Snapshot: one readout per difference.
        let (mut s1, mut s2, mut bad) = (vec![0.0; px], vec![0.0; px], vec![false; px]);
        let light = Illumination::snapshot(hz);
        for _ in 0..n {
            sim.capture(&light, &mut frame);
            for i in 0..px {
                let v = f64::from(frame.dn.data[i]);
                bad[i] |= frame.saturated.data[i] != 0 || !v.is_finite();
                s1[i] += v;
                s2[i] += v * v;
            }
        }
        let x = wells_total(&sim);
        if let Some(v) = mean_pixel_variance(&s1, &s2, &bad, n as f64) {
            snap.electrons.push(x);
            snap.variance_dn2.push(v);
        }
        // Two-shot: LS1-only minus LS2-only, two readouts per difference.
        let (a_light, b_light) = (
            ModeId::TwoShot.illumination(0, hz),
            ModeId::TwoShot.illumination(1, hz),
        );
        let (mut s1, mut s2, mut bad) = (vec![0.0; px], vec![0.0; px], vec![false; px]);
        let mut x = 0.0;
        for _ in 0..n {
            sim.capture(&a_light, &mut frame);
            let xa = wells_total(&sim);
            sim.capture(&b_light, &mut b_frame);
            x = xa + wells_total(&sim);
            for i in 0..px {
                let v = f64::from(frame.dn.data[i]) - f64::from(b_frame.dn.data[i]);
                bad[i] |= frame.saturated.data[i] != 0
                    || b_frame.saturated.data[i] != 0
                    || !v.is_finite();
                s1[i] += v;
                s2[i] += v * v;
            }
        }
        if let Some(v) = mean_pixel_variance(&s1, &s2, &bad, n as f64) {
            two.electrons.push(x);
            two.variance_dn2.push(v);
        }
    }
    Ok((snap, two, sensor))
}

/// The fits, files and summary of both series.
fn finish(
    files: ReportFiles,
    args_json: bool,
    t0: std::time::Instant,
    (snap, two, sensor, n, levels, source): (
        Series,
        Series,
        sdi_core::sensor::SensorParams,
        usize,
        usize,
        String,
    ),
) -> Result<(), CliError> {
    let json = args_json;
    let fit = |s: &Series| {
        let (lo, hi) = s
            .electrons
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            return Err(CliError::Runtime(format!(
                "every level has the same intensity ({lo} electrons): no line to fit \
                 (the scene needs a range of brightness)"
            )));
        }
        linear_fit(&s.electrons, &s.variance_dn2)
            .map_err(|e| CliError::Runtime(format!("line fit: {e}")))
    };
    let (fs, ft) = (fit(&snap)?, fit(&two)?);
    // No read noise seen (zero light and a noiseless input): no ratio.
    let (r, se) = ratio_with_se(ft.intercept, ft.intercept_se, fs.intercept, fs.intercept_se);
    if !(fs.intercept > 0.0 && r.is_finite() && se.is_finite()) {
        return Err(CliError::Runtime(format!(
            "the snapshot intercept is {:.4} DN^2 and the two-shot intercept {:.4} DN^2: \
             no read noise in the data, the intercept ratio is undefined",
            fs.intercept, ft.intercept
        )));
    }
    let mut tsv = String::from("scheme\twell_electrons\tvariance_dn2\n");
    for (name, s) in [("snapshot", &snap), ("two-shot", &two)] {
        for (x, v) in s.electrons.iter().zip(&s.variance_dn2) {
            tsv += &format!("{name}\t{x:.3}\t{v:.5}\n");
        }
    }
    files.write("noise.tsv", tsv.as_bytes())?;
    let mut svg = String::new();
    plot(&mut svg, &sensor.model, &snap, &fs, &two, &ft)
        .map_err(|e| CliError::Runtime(format!("plot: {e}")))?;
    files.write("noise.svg", svg.as_bytes())?;
    let written = files.commit()?;
    let (tsv_path, svg_path) = (&written[0], &written[1]);
    let g = sensor.gain_dn_per_electron();
    let seconds = t0.elapsed().as_secs_f64();
    if json {
        let fit_json = |f: &LinearFit| {
            serde_json::json!({
                "intercept_dn2": f.intercept,
                "intercept_se_dn2": f.intercept_se,
                "slope_dn2_per_electron": f.slope,
                "slope_se_dn2_per_electron": f.slope_se,
            })
        };
        outln!(
            "{}",
            serde_json::json!({
                "sensor": sensor.model,
                "width": sensor.width,
                "height": sensor.height,
                "frames_per_level": n,
                "source": source,
                "levels": levels,
                "seconds": seconds,
                "model_slope_dn2_per_electron": g * g,
                "model_read_variance_dn2": sensor.read_variance_dn2(),
                "snapshot": fit_json(&fs),
                "two_shot": fit_json(&ft),
                "intercept_ratio": r,
                "intercept_ratio_se": se,
                "tsv": tsv_path.display().to_string(),
                "svg": svg_path.display().to_string(),
            })
        )?;
        return Ok(());
    }
    outln!(
        "noise report on the {source}: {} ({}x{} px, {} frames per level, {} levels, {seconds:.1} s)",
        sensor.model,
        sensor.width,
        sensor.height,
        n,
        levels,
    )?;
    outln!(
        "model: slope g^2 = {:.6} DN^2/electron, read variance {:.3} DN^2 (+ 1/12 ADC rounding)",
        g * g,
        sensor.read_variance_dn2()
    )?;
    for (name, f) in [("snapshot", &fs), ("two-shot", &ft)] {
        outln!(
            "{name:<9} variance = ({:.4} +- {:.4}) DN^2 + ({:.6} +- {:.6}) DN^2/electron * I",
            f.intercept,
            f.intercept_se,
            f.slope,
            f.slope_se
        )?;
    }
    outln!("wrote {} and {}", svg_path.display(), tsv_path.display())?;
    outln!(
        "low-light intercept ratio two-shot/snapshot: {r:.3} +- {se:.3} (paper: 1.97 PMD, 1.99 +- 0.37 TI)"
    )?;
    Ok(())
}

fn plot(
    svg: &mut String,
    model: &str,
    snap: &Series,
    fs: &LinearFit,
    two: &Series,
    ft: &LinearFit,
) -> Result<(), String> {
    let pe = |e: DrawingAreaErrorKind<_>| e.to_string();
    let xmax = snap
        .electrons
        .iter()
        .chain(&two.electrons)
        .fold(1.0f64, |a, &b| a.max(b));
    let ymax = snap
        .variance_dn2
        .iter()
        .chain(&two.variance_dn2)
        .fold(1.0f64, |a, &b| a.max(b));
    let root = SVGBackend::with_string(svg, (800, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("{model}: variance vs intensity (Fig. exp_variance)"),
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..xmax * 1.05, 0.0..ymax * 1.05)
        .map_err(pe)?;
    chart
        .configure_mesh()
        .x_desc("expected well electrons per difference, I")
        .y_desc("per-pixel variance, DN^2")
        .draw()
        .map_err(pe)?;
    for (name, s, f, colour) in [("snapshot", snap, fs, BLUE), ("two-shot", two, ft, RED)] {
        chart
            .draw_series(
                s.electrons
                    .iter()
                    .zip(&s.variance_dn2)
                    .map(|(&x, &y)| Circle::new((x, y), 4, colour.filled())),
            )
            .map_err(pe)?;
        let line = vec![(0.0, f.intercept), (xmax, f.intercept + f.slope * xmax)];
        chart
            .draw_series(LineSeries::new(line, colour.stroke_width(2)))
            .map_err(pe)?
            .label(format!(
                "{name}: intercept {:.2} +- {:.2} DN^2",
                f.intercept, f.intercept_se
            ))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(pe)?;
    root.present().map_err(pe)
}
