//! M1: per-pixel statistics over N frames, one pass, f64 (section 6, M1).
//!
//! Welford/Terriberry updates of the central moments M2, M3, M4 never form
//! sum(x^2), so there is no catastrophic cancellation even at 1e7 electrons.
//! Saturated and non-finite samples are kept out and flagged.

use std::collections::VecDeque;

use super::{input_flags, usable, Moments, SeparationError};
use crate::frame::Frame;
use crate::image::{Image, SizeMismatch};
use crate::PixelFlags;

/// Streaming accumulator for M1.
#[derive(Debug, Clone)]
pub struct Welford {
    width: usize,
    height: usize,
    frames: usize,
    count: Vec<u32>,
    mean: Vec<f64>,
    m2: Vec<f64>,
    m3: Vec<f64>,
    m4: Vec<f64>,
    flags: Vec<u8>,
}

impl Welford {
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            frames: 0,
            count: vec![0; n],
            mean: vec![0.0; n],
            m2: vec![0.0; n],
            m3: vec![0.0; n],
            m4: vec![0.0; n],
            flags: vec![0; n],
        }
    }

    /// Frames pushed so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// (width, height) this accumulator takes.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Usable samples of pixel `i` so far.
    pub fn samples(&self, i: usize) -> u32 {
        self.count[i]
    }

    /// Mean of pixel `i`'s usable samples, DN (0 without any).
    pub fn pixel_mean_dn(&self, i: usize) -> f64 {
        self.mean[i]
    }

    /// Unbiased variance (1/(N-1)) of pixel `i`, DN^2; `None` below two usable samples.
    pub fn pixel_variance_dn2(&self, i: usize) -> Option<f64> {
        let n = self.count[i];
        (n >= 2).then(|| self.m2[i] / f64::from(n - 1))
    }

    pub fn reset(&mut self) {
        *self = Self::new(self.width, self.height);
    }

    /// Adds one frame.
    pub fn push(&mut self, frame: &Frame) -> Result<(), SeparationError> {
        check_size(self.width, self.height, frame)?;
        for i in 0..self.count.len() {
            if !usable(frame, i) {
                self.flags[i] |= input_flags(frame, i);
                continue;
            }
            self.add(i, frame.dn.data[i] as f64);
        }
        self.frames += 1;
        Ok(())
    }

    #[inline]
    fn add(&mut self, i: usize, x: f64) {
        let n1 = self.count[i] as f64;
        let n = n1 + 1.0;
        let delta = x - self.mean[i];
        let delta_n = delta / n;
        let delta_n2 = delta_n * delta_n;
        let term1 = delta * delta_n * n1;
        self.mean[i] += delta_n;
        self.m4[i] += term1 * delta_n2 * (n * n - 3.0 * n + 3.0) + 6.0 * delta_n2 * self.m2[i]
            - 4.0 * delta_n * self.m3[i];
        self.m3[i] += term1 * delta_n * (n - 2.0) - 3.0 * delta_n * self.m2[i];
        self.m2[i] += term1;
        self.count[i] += 1;
    }

    /// Removes a sample previously added (exact inverse of `add` for M2 and the mean).
    #[inline]
    fn remove(&mut self, i: usize, x: f64) {
        let n = self.count[i] as f64;
        if n <= 1.0 {
            self.count[i] = 0;
            self.mean[i] = 0.0;
            self.m2[i] = 0.0;
            self.m3[i] = 0.0;
            self.m4[i] = 0.0;
            return;
        }
        let n1 = n - 1.0;
        let mean_old = (n * self.mean[i] - x) / n1;
        let delta = x - mean_old;
        let delta_n = delta / n;
        let delta_n2 = delta_n * delta_n;
        let term1 = delta * delta_n * n1;
        let m2_old = (self.m2[i] - term1).max(0.0);
        let m3_old = self.m3[i] - term1 * delta_n * (n - 2.0) + 3.0 * delta_n * m2_old;
        let m4_old =
            self.m4[i] - term1 * delta_n2 * (n * n - 3.0 * n + 3.0) - 6.0 * delta_n2 * m2_old
                + 4.0 * delta_n * m3_old;
        self.mean[i] = mean_old;
        self.m2[i] = m2_old;
        self.m3[i] = m3_old;
        self.m4[i] = m4_old.max(0.0);
        self.count[i] -= 1;
    }

    /// Mean and unbiased variance (1/(N-1), section 6 M1) per pixel.
    /// Fewer than 2 frames is an error; pixels with fewer than 2 usable
    /// samples are flagged [`PixelFlags::INSUFFICIENT`].
    pub fn moments(&self) -> Result<Moments, SeparationError> {
        if self.frames < 2 {
            return Err(SeparationError::TooFewFrames {
                needed: 2,
                got: self.frames,
            });
        }
        let mut out = Moments::new(self.width, self.height);
        out.flags.data.copy_from_slice(&self.flags);
        for i in 0..self.count.len() {
            let n = self.count[i] as f64;
            if n < 2.0 {
                out.set_insufficient(i);
                continue;
            }
            let var = self.m2[i] / (n - 1.0);
            let m3 = self.m3[i] / n;
            let m4 = self.m4[i] / n;
            out.set_from_central(i, n, self.mean[i], var, m3, Some(m4));
        }
        Ok(out)
    }
}

fn check_size(width: usize, height: usize, frame: &Frame) -> Result<(), SeparationError> {
    SizeMismatch::check((width, height), (frame.width(), frame.height()))?;
    if width * height == 0 {
        return Err(SeparationError::Empty);
    }
    Ok(())
}

/// M1 over the last `window` frames: adds the newest, removes the oldest, and
/// rebuilds from the kept frames every `window` pushes so rounding cannot drift.
/// Until that rebuild, removing a sample x leaves an error of order
/// f64::EPSILON x^2 in the variance (a 1e7 DN outlier: ~0.02 DN^2).
/// The SATURATED and NONFINITE flags describe the frames in the window only.
#[derive(Debug, Clone)]
pub struct SlidingWelford {
    window: usize,
    acc: Welford,
    kept: VecDeque<(Image<f32>, Image<u8>)>,
    since_rebuild: usize,
    /// Saturated / non-finite samples per pixel among the kept frames: flags
    /// are derived from these, since OR-ed bits cannot be taken back when the
    /// offending frame leaves the window.
    saturated: Vec<u32>,
    nonfinite: Vec<u32>,
}

impl SlidingWelford {
    pub fn new(width: usize, height: usize, window: usize) -> Result<Self, SeparationError> {
        if window < 2 {
            return Err(SeparationError::TooFewFrames {
                needed: 2,
                got: window,
            });
        }
        Ok(Self {
            window,
            acc: Welford::new(width, height),
            kept: VecDeque::with_capacity(window + 1),
            since_rebuild: 0,
            saturated: vec![0; width * height],
            nonfinite: vec![0; width * height],
        })
    }

    pub fn push(&mut self, frame: &Frame) -> Result<(), SeparationError> {
        check_size(self.acc.width, self.acc.height, frame)?;
        self.acc.push(frame)?;
        count_unusable(&mut self.saturated, &mut self.nonfinite, frame);
        self.kept
            .push_back((frame.dn.clone(), frame.saturated.clone()));
        if self.kept.len() > self.window {
            if let Some((dn, sat)) = self.kept.pop_front() {
                for i in 0..dn.data.len() {
                    let x = dn.data[i];
                    if sat.data[i] == 0 && x.is_finite() {
                        self.acc.remove(i, x as f64);
                    }
                    if sat.data[i] != 0 {
                        self.saturated[i] -= 1;
                    }
                    if !x.is_finite() {
                        self.nonfinite[i] -= 1;
                    }
                }
                self.acc.frames -= 1;
            }
        }
        self.since_rebuild += 1;
        if self.since_rebuild >= self.window {
            self.rebuild();
        }
        Ok(())
    }

    fn rebuild(&mut self) {
        self.acc.reset();
        for (dn, sat) in &self.kept {
            for i in 0..dn.data.len() {
                let x = dn.data[i];
                if sat.data[i] != 0 {
                    self.acc.flags[i] |= PixelFlags::SATURATED.bits();
                }
                if !x.is_finite() {
                    self.acc.flags[i] |= PixelFlags::NONFINITE.bits();
                }
                if sat.data[i] == 0 && x.is_finite() {
                    self.acc.add(i, x as f64);
                }
            }
            self.acc.frames += 1;
        }
        self.since_rebuild = 0;
    }

    /// (width, height) this window accepts.
    pub fn size(&self) -> (usize, usize) {
        (self.acc.width, self.acc.height)
    }

    /// Frames currently in the window.
    pub fn len(&self) -> usize {
        self.kept.len()
    }

    pub fn is_empty(&self) -> bool {
        self.kept.is_empty()
    }

    pub fn moments(&self) -> Result<Moments, SeparationError> {
        let mut m = self.acc.moments()?;
        for (i, f) in m.flags.data.iter_mut().enumerate() {
            *f &= !(PixelFlags::SATURATED.bits() | PixelFlags::NONFINITE.bits());
            if self.saturated[i] > 0 {
                *f |= PixelFlags::SATURATED.bits();
            }
            if self.nonfinite[i] > 0 {
                *f |= PixelFlags::NONFINITE.bits();
            }
        }
        Ok(m)
    }
}

/// Counts the saturated and non-finite samples of `frame` per pixel.
fn count_unusable(saturated: &mut [u32], nonfinite: &mut [u32], frame: &Frame) {
    for i in 0..saturated.len() {
        if frame.saturated.data[i] != 0 {
            saturated[i] += 1;
        }
        if !frame.dn.data[i].is_finite() {
            nonfinite[i] += 1;
        }
    }
}
