//! The report on simulator data: the dark frame, then M1 over N streamed
//! frames against the mean of their truths, then the single-frame
//! estimators on the first frame.

use std::time::{Duration, Instant};

use sdi_core::calibration::DarkCalibration;
use sdi_core::dark_frame::DarkAccumulator;
use sdi_core::modulation::Illumination;
use sdi_core::scene::{ColourChart, SceneSpec};
use sdi_core::sensor::{mixing_with_adc, SkellamMixing};
use sdi_core::separation::{pool_moments, unmix, PoolParams, UnmixOptions, Welford};
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

use super::args::{Chosen, Estimator, SeparationReportArgs};
use super::metrics::{m1_floor, row};
use super::single_frame::{m2_rows, m3_rows};
use super::{Report, ReportError, Row, Truth};

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

/// Runs the report on the simulator (frames streamed, constant memory in N).
pub(super) fn run(
    args: &SeparationReportArgs,
    name: &str,
    scene: SceneSpec,
) -> Result<Report, ReportError> {
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
