//! A stack of frames separated by one estimator, as `sdictl separate` and
//! Python's `sdi.separate` run it (one definition): frames go in one at a
//! time; M1 and M1-pooled give one output at the end (or, over a sliding
//! window, one per frame), M2, M3 and Skellam ML one output per frame.

use super::{
    auto_segment, bilateral_exact, noise_sigma, pool_moments, segment_moments, skellam_ml_pixel,
    unmix_into, unmix_local_into, BilateralParams, PoolParams, SegmentParams, SeparableBilateral,
    Separated, SeparationError, SlidingWelford, UnmixOptions, Welford,
};
use crate::sensor::SkellamMixing;
use crate::{Frame, Image, PixelFlags};

/// Longest temporal window, frames.
pub const MAX_BATCH_WINDOW: usize = 4096;
/// Skellam ML's window when none is given, frames.
pub const DEFAULT_ML_WINDOW: usize = 16;
/// Smallest frame M3 runs the separable filter on; below it the exact one
/// (no block set-up).
const M3_EXACT_BELOW_PIXELS: usize = 64;

/// The estimator (paper section 6, and two beyond it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, strum::Display, strum::EnumString, strum::EnumIter)]
#[strum(serialize_all = "kebab-case")]
pub enum BatchMethod {
    /// Mean and variance over the frames (M1).
    M1,
    /// M1, then edge-aware pooling of the per-pixel moments.
    M1Pooled,
    /// Statistics over segments of each frame (M2).
    M2,
    /// Bilateral-weighted statistics of each frame (M3); the range sigma is
    /// a multiple of the frame's own noise.
    M3,
    /// Per-pixel Skellam maximum likelihood over a temporal window.
    Ml,
}

/// What a separation run is told.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchParams {
    pub method: BatchMethod,
    /// Temporal window, frames: M1 (sliding, one output per frame) and ML
    /// (default [`DEFAULT_ML_WINDOW`]).
    pub window: Option<usize>,
    /// M2: segment labels ([`super::IGNORE_LABEL`] = none); None = automatic.
    pub labels: Option<Image<u32>>,
    /// M3: spatial sigma, px.
    pub sigma_domain_px: f64,
    /// M3: range sigma in units of the frame's own noise.
    pub range_sigmas: f64,
    pub options: UnmixOptions,
}

impl BatchParams {
    /// `method` with the defaults of `sdictl separate`.
    pub fn new(method: BatchMethod) -> Self {
        Self {
            method,
            window: None,
            labels: None,
            sigma_domain_px: 3.0,
            range_sigmas: 3.0,
            options: UnmixOptions::default(),
        }
    }
}

/// Why a run refused its set-up or its frames.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BatchError {
    #[error("gain rho*eta = {0} DN/electron cannot be inverted (H is singular)")]
    Singular(f64),
    #[error("read variance {0} DN^2 must be >= 0")]
    ReadVariance(f64),
    #[error("segment labels apply to method m2 only")]
    LabelsNotM2,
    #[error("a window applies to m1 and ml only")]
    WindowNotM1OrMl,
    #[error("window of {0} frames; allowed 2..={MAX_BATCH_WINDOW}")]
    WindowRange(usize),
    #[error("M1 needs at least 2 frames: {0}")]
    M1TooFewFrames(SeparationError),
    #[error("separation: {0}")]
    Separation(#[from] SeparationError),
}

/// The estimator's state between frames.
enum State {
    M1(Welford),
    Sliding(SlidingWelford),
    M2,
    M3(Box<SeparableBilateral>),
    Ml(MlState),
}

/// A separation run over frames of one size.
pub struct BatchSeparator {
    params: BatchParams,
    h: SkellamMixing,
    width: usize,
    height: usize,
    state: State,
    frames: usize,
}

impl BatchSeparator {
    /// Checks H (g^2 normal, read variance >= 0) and the parameters before any frame.
    pub fn new(
        params: BatchParams,
        h: SkellamMixing,
        width: usize,
        height: usize,
    ) -> Result<Self, BatchError> {
        check_mixing(&h)?;
        if params.labels.is_some() && params.method != BatchMethod::M2 {
            return Err(BatchError::LabelsNotM2);
        }
        if let Some(w) = params.window {
            if !matches!(params.method, BatchMethod::M1 | BatchMethod::Ml) {
                return Err(BatchError::WindowNotM1OrMl);
            }
            if !(2..=MAX_BATCH_WINDOW).contains(&w) {
                return Err(BatchError::WindowRange(w));
            }
        }
        let state = match (params.method, params.window) {
            (BatchMethod::M1 | BatchMethod::M1Pooled, None) => {
                State::M1(Welford::new(width, height))
            }
            (BatchMethod::M1 | BatchMethod::M1Pooled, Some(win)) => {
                State::Sliding(SlidingWelford::new(width, height, win)?)
            }
            (BatchMethod::M2, _) => State::M2,
            (BatchMethod::M3, _) => State::M3(Box::new(SeparableBilateral::new())),
            (BatchMethod::Ml, win) => State::Ml(MlState::new(
                width,
                height,
                win.unwrap_or(DEFAULT_ML_WINDOW),
            )?),
        };
        Ok(Self {
            params,
            h,
            width,
            height,
            state,
            frames: 0,
        })
    }

    /// True when the run gives one output, at [`Self::finish`] (M1 or
    /// M1-pooled without a window); else one per frame, from [`Self::push`].
    pub fn single_output(&self) -> bool {
        matches!(self.state, State::M1(_))
    }

    /// Frames taken so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Takes one frame; true when `out` now holds the output for it.
    pub fn push(&mut self, frame: &Frame, out: &mut Separated) -> Result<bool, BatchError> {
        self.frames += 1;
        let (h, options) = (&self.h, self.params.options);
        match &mut self.state {
            State::M1(acc) => {
                acc.push(frame)?;
                return Ok(false);
            }
            State::Sliding(acc) => {
                acc.push(frame)?;
                if acc.len() < 2 {
                    insufficient(out, self.width, self.height);
                } else {
                    unmix_into(&acc.moments()?, h, options, out)?;
                }
            }
            State::M2 => {
                let m = match &self.params.labels {
                    Some(l) => segment_moments(frame, l, None),
                    None => auto_segment(frame, SegmentParams::default())
                        .and_then(|s| segment_moments(frame, &s.labels, Some(&s.interior))),
                }?;
                unmix_into(&m, h, options, out)?;
            }
            State::M3(separable) => {
                let p = BilateralParams::new(
                    self.params.sigma_domain_px,
                    self.params.range_sigmas * noise_sigma(frame),
                );
                if self.width * self.height < M3_EXACT_BELOW_PIXELS {
                    unmix_into(&bilateral_exact(frame, p)?, h, options, out)?;
                } else {
                    unmix_local_into(separable.compute(frame, p)?, h, options, out)?;
                }
            }
            State::Ml(ml) => ml.push(frame, h, out)?,
        }
        Ok(true)
    }

    /// After the last frame: true when `out` now holds the one output of
    /// M1 or M1-pooled.
    pub fn finish(&mut self, out: &mut Separated) -> Result<bool, BatchError> {
        let State::M1(acc) = &self.state else {
            return Ok(false);
        };
        let m = acc.moments().map_err(BatchError::M1TooFewFrames)?;
        let m = if self.params.method == BatchMethod::M1Pooled {
            pool_moments(&m, PoolParams::default())?
        } else {
            m
        };
        unmix_into(&m, &self.h, self.params.options, out)?;
        Ok(true)
    }
}

/// g^2 must be normal (H invertible in f32) and the read variance >= 0.
fn check_mixing(h: &SkellamMixing) -> Result<(), BatchError> {
    let g = h.gain_dn_per_electron;
    let r = h.read_variance_dn2;
    if !(g.is_finite() && g > 0.0 && (g * g).is_normal() && (1.0 / (g * g)) < f32::MAX as f64) {
        return Err(BatchError::Singular(g));
    }
    if !(r.is_finite() && r >= 0.0) {
        return Err(BatchError::ReadVariance(r));
    }
    Ok(())
}

/// Makes an output fit to write: an estimate that is not finite becomes 0
/// with an infinite standard error and the NONFINITE flag; a NaN standard
/// error becomes infinite. Returns how many estimates were not finite.
pub fn sanitize(s: &mut Separated) -> usize {
    const NONFINITE: u8 = PixelFlags::NONFINITE.bits();
    let mut nonfinite = 0;
    for i in 0..s.flags.data.len() {
        let (p, m) = (s.i_plus_electrons.data[i], s.i_minus_electrons.data[i]);
        if !(p.is_finite() && m.is_finite()) {
            s.i_plus_electrons.data[i] = 0.0;
            s.i_minus_electrons.data[i] = 0.0;
            s.i_plus_se_electrons.data[i] = f32::INFINITY;
            s.i_minus_se_electrons.data[i] = f32::INFINITY;
            s.flags.data[i] |= NONFINITE;
            nonfinite += 1;
        }
        for se in [
            &mut s.i_plus_se_electrons.data[i],
            &mut s.i_minus_se_electrons.data[i],
        ] {
            if se.is_nan() {
                *se = f32::INFINITY;
            }
        }
    }
    nonfinite
}

/// Every pixel flagged INSUFFICIENT: 0 with infinite standard error.
fn insufficient(sep: &mut Separated, w: usize, h: usize) {
    sep.ensure_size(w, h);
    sep.i_plus_electrons.data.fill(0.0);
    sep.i_minus_electrons.data.fill(0.0);
    sep.i_plus_se_electrons.data.fill(f32::INFINITY);
    sep.i_minus_se_electrons.data.fill(f32::INFINITY);
    sep.flags.data.fill(PixelFlags::INSUFFICIENT.bits());
}

/// Skellam ML per frame over the last `window` frames of each pixel;
/// standard errors from the same window's moments (non-negative unmixing).
struct MlState {
    acc: SlidingWelford,
    /// The last `window` frames, NaN where a sample is unusable.
    ring: Vec<f32>,
    window: usize,
    filled: usize,
    head: usize,
    samples: Vec<f64>,
}

impl MlState {
    fn new(w: usize, h: usize, window: usize) -> Result<Self, SeparationError> {
        Ok(Self {
            acc: SlidingWelford::new(w, h, window)?,
            ring: vec![f32::NAN; window * w * h],
            window,
            filled: 0,
            head: 0,
            samples: Vec::with_capacity(window),
        })
    }

    fn push(
        &mut self,
        frame: &Frame,
        h: &SkellamMixing,
        sep: &mut Separated,
    ) -> Result<(), SeparationError> {
        const INSUFFICIENT: u8 = PixelFlags::INSUFFICIENT.bits();
        const SATURATED: u8 = PixelFlags::SATURATED.bits();
        let (w, ht) = (frame.width(), frame.height());
        let npx = w * ht;
        let nonneg = UnmixOptions {
            subtract_read_noise: true,
            nonnegative: true,
        };
        self.acc.push(frame)?;
        let slot = &mut self.ring[self.head * npx..(self.head + 1) * npx];
        for (i, s) in slot.iter_mut().enumerate() {
            *s = if frame.saturated.data[i] == 0 {
                frame.dn.data[i]
            } else {
                f32::NAN
            };
        }
        self.head = (self.head + 1) % self.window;
        self.filled = (self.filled + 1).min(self.window);
        if self.acc.len() < 2 {
            insufficient(sep, w, ht);
        } else {
            unmix_into(&self.acc.moments()?, h, nonneg, sep)?;
        }
        for i in 0..npx {
            self.samples.clear();
            self.samples
                .extend((0..self.filled).map(|k| f64::from(self.ring[k * npx + i])));
            match skellam_ml_pixel(&self.samples, h) {
                Ok(fit) => {
                    sep.i_plus_electrons.data[i] = fit.i_plus_electrons as f32;
                    sep.i_minus_electrons.data[i] = fit.i_minus_electrons as f32;
                    sep.flags.data[i] &= !INSUFFICIENT;
                }
                Err(_) => {
                    sep.i_plus_electrons.data[i] = 0.0;
                    sep.i_minus_electrons.data[i] = 0.0;
                    sep.i_plus_se_electrons.data[i] = f32::INFINITY;
                    sep.i_minus_se_electrons.data[i] = f32::INFINITY;
                    sep.flags.data[i] |= INSUFFICIENT;
                }
            }
            if frame.saturated.data[i] != 0 {
                sep.flags.data[i] |= SATURATED;
            }
        }
        Ok(())
    }
}
