//! The report on measured data: the truth from LS1-only and LS2-only
//! frames, the estimators on the both-sources frames, every input streamed.

use std::path::Path;
use std::time::{Duration, Instant};

use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    auto_segment, noise_sigma, pool_moments, segment_moments, unmix, unmix_local_into,
    BilateralParams, PoolParams, SegmentParams, SeparableBilateral, Separated, SeparationError,
    UnmixOptions, Welford,
};
use sdi_core::Frame;

use super::args::{Chosen, Estimator, SeparationReportArgs, MAX_REPORT_FRAMES};
use super::metrics::{m1_floor, row};
use super::{Report, ReportError, Row, Truth};
use crate::exit::CliError;
use crate::offline::frames::{FrameInput, InputInfo};
use crate::offline::separate::choose_mixing;

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
) -> Result<(usize, InputInfo), CliError> {
    let (mut input, info) = FrameInput::open(path)?;
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
pub(super) fn run_measured(args: &SeparationReportArgs) -> Result<Report, CliError> {
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
    let h = choose_mixing(None, sensor, &both.info)?.h;
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
    info: InputInfo,
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
