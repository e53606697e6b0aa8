//! Per-frame separation for the daemon: each frame in, the two separated
//! channels out (M3 on every frame, or M1 over a sliding window).

use super::{
    bilateral_separable, unmix, BilateralGrid, BilateralParams, Separated, SeparationError,
    SlidingWelford, UnmixOptions,
};
use crate::frame::Frame;
use crate::sensor::SkellamMixing;

/// From this sigma_domain on the bilateral grid beats the separable M3.
const GRID_FROM_SIGMA_PX: f64 = 2.0;

/// Which estimator the live separator runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LiveMethod {
    /// Fast M3 on every frame (one-frame latency, moving scenes): the
    /// bilateral grid from sigma_domain 2 px up, the separable variant below
    /// (faster there; see `cargo bench -p sdi-core --bench m3_vs_opencv`).
    Bilateral(BilateralParams),
    /// M1 over the last `frames` frames (static scenes, best accuracy).
    SlidingWindow { frames: usize },
}

/// Turns a stream of frames into I+ and I- images.
#[derive(Debug, Clone)]
pub struct LiveSeparator {
    method: LiveMethod,
    h: SkellamMixing,
    options: UnmixOptions,
    window: Option<SlidingWelford>,
    grid: BilateralGrid,
    last: Option<Separated>,
}

impl LiveSeparator {
    pub fn new(method: LiveMethod, h: SkellamMixing, options: UnmixOptions) -> Self {
        Self {
            method,
            h,
            options,
            window: None,
            grid: BilateralGrid::new(),
            last: None,
        }
    }

    /// Feeds one frame. Returns the separated channels, or `Ok(None)` while a
    /// sliding window holds fewer than two frames.
    pub fn process(&mut self, frame: &Frame) -> Result<Option<&Separated>, SeparationError> {
        let windowed;
        let moments = match self.method {
            LiveMethod::Bilateral(p) if p.sigma_domain_px >= GRID_FROM_SIGMA_PX => {
                self.grid.compute(frame, p)?
            }
            LiveMethod::Bilateral(p) => {
                windowed = bilateral_separable(frame, p)?;
                &windowed
            }
            LiveMethod::SlidingWindow { frames } => {
                let (w, h) = (frame.width(), frame.height());
                let stale = self.window.as_ref().is_none_or(|s| s.size() != (w, h));
                if stale {
                    self.window = Some(SlidingWelford::new(w, h, frames)?);
                }
                let Some(window) = self.window.as_mut() else {
                    return Ok(None);
                };
                window.push(frame)?;
                if window.len() < 2 {
                    return Ok(None);
                }
                windowed = window.moments()?;
                &windowed
            }
        };
        self.last = Some(unmix(moments, &self.h, self.options)?);
        Ok(self.last.as_ref())
    }

    /// The most recent output.
    pub fn last(&self) -> Option<&Separated> {
        self.last.as_ref()
    }
}
