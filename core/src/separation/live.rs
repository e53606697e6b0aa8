//! Per-frame separation for the daemon: each frame in, the two separated
//! channels out (M3 on every frame, or M1 over a sliding window).

use super::{
    unmix_into, unmix_local_into, BilateralGrid, BilateralParams, SeparableBilateral, Separated,
    SeparationError, SlidingWelford, UnmixOptions,
};
use crate::frame::Frame;
use crate::sensor::SkellamMixing;

/// From this sigma_domain on the bilateral grid (O(1) per pixel) beats the
/// separable M3 (O(sigma) per pixel) at 640x480 on one core: about 3.5 ms CPU
/// each at 4.5 (`cargo bench -p sdi-core --bench m3_vs_opencv`), so no
/// sigma_domain costs more than the separable M3 at radius 12. The grid's
/// error against the exact M3 is the lower in the mean and the higher in the
/// variance from here to 6 (the bench prints both).
const GRID_FROM_SIGMA_PX: f64 = 4.5;

/// Which estimator the live separator runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LiveMethod {
    /// Fast M3 on every frame (one-frame latency, moving scenes): the
    /// separable variant, or the bilateral grid from sigma_domain 4.5 px up
    /// (see `cargo bench -p sdi-core --bench m3_vs_opencv`).
    Bilateral(BilateralParams),
    /// M1 over the last `frames` frames (static scenes, best accuracy).
    SlidingWindow { frames: usize },
}

/// M3's default live parameters: a 5x5-ish window, range sigma of a few noise sigmas.
pub const DEFAULT_BILATERAL: BilateralParams = BilateralParams {
    sigma_domain_px: 1.5,
    sigma_range_dn: 20.0,
    radius_px: 0,
};

/// How the live separator separates, and with which H (the separation
/// mode's setting).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveSeparatorConfig {
    pub method: LiveMethod,
    /// H from the sensor parameters or the photon-transfer calibration.
    pub h: SkellamMixing,
    pub options: UnmixOptions,
}

impl LiveSeparatorConfig {
    pub fn new(method: LiveMethod, h: SkellamMixing) -> Self {
        Self {
            method,
            h,
            options: UnmixOptions::default(),
        }
    }
}

/// Longest sliding window of the live separator: it holds two images of f64
/// sums per frame.
pub const MAX_LIVE_WINDOW_FRAMES: usize = 1000;

impl LiveMethod {
    /// Refuses parameters the separator cannot run with: M3's sigmas
    /// ([`BilateralParams::validate`]), a window outside 2..=[`MAX_LIVE_WINDOW_FRAMES`].
    pub fn validate(&self) -> Result<(), SeparationError> {
        match *self {
            LiveMethod::Bilateral(p) => p.validate(),
            LiveMethod::SlidingWindow { frames } => SeparationError::check(
                "window_frames",
                frames as f64,
                (2..=MAX_LIVE_WINDOW_FRAMES).contains(&frames),
                "2..=1000",
            ),
        }
    }
}

impl Default for LiveSeparatorConfig {
    /// M3 with the default sensor preset's H (pipelines built without a sensor).
    fn default() -> Self {
        Self::new(
            LiveMethod::Bilateral(DEFAULT_BILATERAL),
            crate::sensor::SensorPreset::TiOpt8241.params().skellam(),
        )
    }
}

/// Turns a stream of frames into I+ and I- images.
#[derive(Debug, Clone)]
pub struct LiveSeparator {
    method: LiveMethod,
    h: SkellamMixing,
    options: UnmixOptions,
    window: Option<SlidingWelford>,
    grid: BilateralGrid,
    separable: SeparableBilateral,
    out: Separated,
    has_output: bool,
}

impl LiveSeparator {
    /// The separator `config` describes.
    pub fn from_config(config: LiveSeparatorConfig) -> Self {
        Self::new(config.method, config.h, config.options)
    }

    pub fn new(method: LiveMethod, h: SkellamMixing, options: UnmixOptions) -> Self {
        Self {
            method,
            h,
            options,
            window: None,
            grid: BilateralGrid::new(),
            separable: SeparableBilateral::new(),
            out: Separated::default(),
            has_output: false,
        }
    }

    /// Feeds one frame. Returns the separated channels, or `Ok(None)` while a
    /// sliding window holds fewer than two frames.
    pub fn process(&mut self, frame: &Frame) -> Result<Option<&Separated>, SeparationError> {
        let (h, options, out) = (&self.h, self.options, &mut self.out);
        match self.method {
            LiveMethod::Bilateral(p) if p.sigma_domain_px >= GRID_FROM_SIGMA_PX => {
                unmix_local_into(self.grid.compute(frame, p)?, h, options, out)?;
            }
            LiveMethod::Bilateral(p) => {
                unmix_local_into(self.separable.compute(frame, p)?, h, options, out)?;
            }
            LiveMethod::SlidingWindow { frames } => {
                let (w, ht) = (frame.width(), frame.height());
                let stale = self.window.as_ref().is_none_or(|s| s.size() != (w, ht));
                if stale {
                    self.window = Some(SlidingWelford::new(w, ht, frames)?);
                }
                let Some(window) = self.window.as_mut() else {
                    return Ok(None);
                };
                window.push(frame)?;
                if window.len() < 2 {
                    return Ok(None);
                }
                unmix_into(&window.moments()?, h, options, out)?;
            }
        }
        self.has_output = true;
        Ok(Some(&self.out))
    }

    /// The most recent output.
    pub fn last(&self) -> Option<&Separated> {
        self.has_output.then_some(&self.out)
    }
}
