//! Photon-transfer calibration run by the frame loop (EMVA 1288 style): LS1
//! alone at several exposures, per-pixel temporal mean and variance at each
//! (M1, Welford), then the straight-line fit sigma^2 = g |mu| + sigma_read^2
//! (eq. skellamvar with I- = 0) for g = rho eta and the read variance.

use sdi_core::calibration::{fit_photon_transfer, PhotonTransferFit, PtcPoint};
use sdi_core::dark_frame::subtract_dark;
use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::separation::Welford;
use sdi_core::{Frame, Image};

use crate::backend::CaptureSettings;

/// Exposures of the levels, as fractions of the current exposure.
pub const LEVELS: [f64; 5] = [0.2, 0.4, 0.6, 0.8, 1.0];

/// What the frame loop does after feeding a frame.
#[derive(Debug)]
pub enum Step {
    /// Keep capturing with the same settings.
    Continue,
    /// Apply [`PtcJob::settings`] (the next level) before the next frame.
    NextLevel,
    /// Finished: restore [`PtcJob::base`] and report.
    Done(Result<PhotonTransferFit, String>),
}

pub struct PtcJob {
    base: CaptureSettings,
    frames_per_level: u32,
    level: usize,
    /// Frames seen at this level, including the discarded first one.
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

    /// The settings the calibration started from (restored at the end).
    pub fn base(&self) -> CaptureSettings {
        self.base
    }

    /// Capture settings of the current level.
    pub fn settings(&self) -> CaptureSettings {
        CaptureSettings {
            exposure_us: self.base.exposure_us * LEVELS[self.level.min(LEVELS.len() - 1)],
            ..self.base
        }
    }

    /// LS1 alone, driven by f: all its light lands in I+.
    pub fn illumination(carrier_hz: f64) -> Illumination {
        Illumination {
            modulation: ModulationPattern::square_wave(carrier_hz),
            ls1: SourceDrive::Modulated,
            ls2: SourceDrive::Off,
        }
    }

    /// Fraction done, 0..=1.
    pub fn progress(&self) -> f64 {
        let per = f64::from(self.frames_per_level + 1);
        (self.level as f64 * per + f64::from(self.seen)) / (LEVELS.len() as f64 * per)
    }

    /// Feeds one frame captured with [`Self::settings`].
    pub fn push(&mut self, frame: &Frame) -> Step {
        self.seen += 1;
        // The first frame of a level may still carry the previous exposure.
        if self.seen == 1 {
            return Step::Continue;
        }
        self.scratch.clone_from(frame);
        if let Some(d) = self.dark.as_ref().filter(|d| d.same_size(&frame.dn)) {
            subtract_dark(&mut self.scratch.dn.data, &d.data);
        }
        if let Err(e) = self.welford.push(&self.scratch) {
            return Step::Done(Err(e.to_string()));
        }
        if self.seen <= self.frames_per_level {
            return Step::Continue;
        }
        let point = self
            .welford
            .moments()
            .map_err(|e| e.to_string())
            .and_then(|m| PtcPoint::from_moments(&m).map_err(|e| e.to_string()));
        match point {
            Ok(p) => self.points.push(p),
            Err(e) => return Step::Done(Err(e)),
        }
        self.welford.reset();
        self.seen = 0;
        self.level += 1;
        if self.level < LEVELS.len() {
            Step::NextLevel
        } else {
            Step::Done(fit_photon_transfer(&self.points).map_err(|e| e.to_string()))
        }
    }
}
