//! Photon-transfer calibration run by the frame loop (EMVA 1288 style): LS1
//! alone at several exposures, per-pixel temporal mean and variance at each
//! (M1, Welford), then the straight-line fit sigma^2 = g |mu| + sigma_read^2
//! (eq. skellamvar with I- = 0) for g = rho eta and the read variance.

use sdi_core::calibration::{fit_photon_transfer, CalibrationError, PhotonTransferFit, PtcPoint};
use sdi_core::dark_frame::subtract_dark;
use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::separation::{SeparationError, Welford};
use sdi_core::{Frame, Image};

use crate::backend::CaptureSettings;
use crate::job::{Job, Step};

/// Exposures of the levels, as fractions of the current exposure.
pub const LEVELS: [f64; 5] = [0.2, 0.4, 0.6, 0.8, 1.0];

/// Why the photon-transfer calibration gave no fit.
#[derive(Debug, thiserror::Error)]
pub enum PtcError {
    /// A level's frames gave no moments (a frame of another size, too few).
    #[error(transparent)]
    Moments(#[from] SeparationError),
    /// The levels gave no point or no fit.
    #[error(transparent)]
    Fit(#[from] CalibrationError),
}

pub struct PtcJob {
    base: CaptureSettings,
    frames_per_level: u32,
    level: usize,
    /// Frames fed at this level (the frame loop skips the first one after
    /// each exposure change: [`crate::job::Settling`]).
    seen: u32,
    welford: Welford,
    points: Vec<PtcPoint>,
    dark: Option<Image<f32>>,
    scratch: Frame,
}

impl PtcJob {
    pub fn new(
        base: CaptureSettings,
        frames_per_level: u32,
        dark: Option<Image<f32>>,
        width: usize,
        height: usize,
    ) -> Self {
        Self {
            base,
            frames_per_level: frames_per_level.max(2),
            level: 0,
            seen: 0,
            welford: Welford::new(width, height),
            points: Vec::with_capacity(LEVELS.len()),
            dark,
            scratch: Frame::new(width, height),
        }
    }

    /// Capture settings of the current level.
    fn settings(&self) -> CaptureSettings {
        CaptureSettings {
            exposure_us: self.base.exposure_us * LEVELS[self.level.min(LEVELS.len() - 1)],
            ..self.base
        }
    }
}

impl Job for PtcJob {
    type Output = Result<PhotonTransferFit, PtcError>;

    /// The first level's exposure.
    fn prepare(&mut self) -> Option<CaptureSettings> {
        Some(self.settings())
    }

    /// LS1 alone, driven by f: all its light lands in I+.
    fn illumination(&self, carrier_hz: f64) -> Illumination {
        Illumination {
            modulation: ModulationPattern::square_wave(carrier_hz),
            ls1: SourceDrive::Modulated,
            ls2: SourceDrive::Off,
        }
    }

    /// Feeds one frame captured with the current level's settings.
    fn process(&mut self, frame: &Frame) -> Step<Self::Output> {
        self.seen += 1;
        self.scratch.clone_from(frame);
        if let Some(d) = self.dark.as_ref().filter(|d| d.same_size(&frame.dn)) {
            subtract_dark(&mut self.scratch.dn.data, &d.data);
        }
        if let Err(e) = self.welford.push(&self.scratch) {
            return Step::Done(Err(e.into()));
        }
        if self.seen < self.frames_per_level {
            return Step::Continue;
        }
        let point = self
            .welford
            .moments()
            .map_err(PtcError::from)
            .and_then(|m| PtcPoint::from_moments(&m).map_err(PtcError::from));
        match point {
            Ok(p) => self.points.push(p),
            Err(e) => return Step::Done(Err(e)),
        }
        self.welford.reset();
        self.seen = 0;
        self.level += 1;
        if self.level < LEVELS.len() {
            Step::Configure(self.settings())
        } else {
            Step::Done(fit_photon_transfer(&self.points).map_err(PtcError::from))
        }
    }

    /// The settings the calibration started from.
    fn restore(&self) -> Option<CaptureSettings> {
        Some(self.base)
    }

    /// Frames of the levels done and of this one.
    fn progress(&self) -> u32 {
        (self.level as u32)
            .saturating_mul(self.frames_per_level)
            .saturating_add(self.seen)
    }
}
