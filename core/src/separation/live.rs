//! Per-frame separation for the daemon: each frame in, the two separated
//! channels out (M3 on every frame, or M1 over a sliding window).

use super::{
    bilateral_separable, unmix, BilateralParams, Separated, SeparationError, SlidingWelford,
    UnmixOptions,
};
use crate::frame::Frame;
use crate::sensor::SkellamMixing;

/// Which estimator the live separator runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LiveMethod {
    /// Fast M3 on every frame (one-frame latency, moving scenes).
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
    last: Option<Separated>,
}

impl LiveSeparator {
    pub fn new(method: LiveMethod, h: SkellamMixing, options: UnmixOptions) -> Self {
        Self {
            method,
            h,
            options,
            window: None,
            last: None,
        }
    }

    /// Feeds one frame. Returns the separated channels, or `Ok(None)` while a
    /// sliding window holds fewer than two frames.
    pub fn process(&mut self, frame: &Frame) -> Result<Option<&Separated>, SeparationError> {
        let moments = match self.method {
            LiveMethod::Bilateral(p) => bilateral_separable(frame, p)?,
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
                window.moments()?
            }
        };
        self.last = Some(unmix(&moments, &self.h, self.options)?);
        Ok(self.last.as_ref())
    }

    /// The most recent output.
    pub fn last(&self) -> Option<&Separated> {
        self.last.as_ref()
    }
}
