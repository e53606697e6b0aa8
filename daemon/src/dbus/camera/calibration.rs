//! The calibration jobs: the dark frame, photon transfer and the phase
//! calibration, and the storing of their fits in the state directory.

use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::Connection;

use super::Camera;
use crate::calibration_store;
use crate::dbus::errors::{calibration_failed, dark_failed, phase_failed, SdiError};
use crate::dbus::job_slot::JobKind;
use crate::frame_loop::{Command, DarkStats};
use crate::phase_calibration::PhaseFit;
use sdi_api::{CalibrationReply, DarkFrameReply, PhaseCalibrationReply};
use sdi_core::calibration::{CalibrationRecord, PhaseRecord, PhotonTransferFit};

/// The reply of CaptureDarkFrame (core's statistics, the API's struct).
pub(super) fn dark_frame_reply(s: &DarkStats) -> DarkFrameReply {
    DarkFrameReply {
        frames: s.frames,
        mean_dn: s.mean_dn,
        read_noise_variance_dn2: s.read_noise_variance_dn2,
        fixed_pattern_sigma_dn: s.fixed_pattern_sigma_dn,
    }
}

impl Camera {
    /// A dark-frame capture of `frames` as a job of its own.
    pub(super) async fn dark_frame_job(
        &self,
        frames: u32,
        hdr: &Header<'_>,
        conn: &Connection,
        emitter: &SignalEmitter<'_>,
    ) -> Result<DarkStats, SdiError> {
        Self::check_frames(frames, 1)?;
        let captures = frames.saturating_add(2);
        let mut job = self
            .begin_job(JobKind::DarkFrame, frames, captures, hdr, conn)
            .await?;
        let _ = self.job_changed(emitter).await;
        self.job_step(&mut job, emitter, |tx| Command::CaptureDark(frames, tx))
            .await?
            .map_err(dark_failed)
    }

    /// The calibration: the dark frame, then photon transfer, one job.
    pub(super) async fn calibration_job(
        &self,
        frames: u32,
        hdr: &Header<'_>,
        conn: &Connection,
        emitter: &SignalEmitter<'_>,
    ) -> Result<(DarkStats, sdi_core::calibration::PhotonTransferFit), SdiError> {
        Self::check_frames(frames, 2)?;
        let levels = crate::photon_transfer::LEVELS.len() as u32;
        let total = frames.saturating_mul(levels + 1);
        // Two captures to settle at the start and at each level.
        let captures = total.saturating_add(2 * (levels + 1));
        let mut job = self
            .begin_job(JobKind::Calibration, total, captures, hdr, conn)
            .await?;
        let _ = self.job_changed(emitter).await;
        let dark = self
            .job_step(&mut job, emitter, |tx| Command::CaptureDark(frames, tx))
            .await?
            .map_err(dark_failed)?;
        self.job_step_done(&job, frames);
        let fit = self
            .job_step(&mut job, emitter, |tx| Command::PhotonTransfer(frames, tx))
            .await?
            .map_err(calibration_failed)?;
        Ok((dark, fit))
    }

    /// The phase calibration of `frames` as a job.
    pub(super) async fn phase_job(
        &self,
        frames: u32,
        hdr: &Header<'_>,
        conn: &Connection,
        emitter: &SignalEmitter<'_>,
    ) -> Result<crate::phase_calibration::PhaseFit, SdiError> {
        Self::check_frames(frames, 1)?;
        let captures = frames.saturating_add(crate::phase_calibration::FRAMES_IN_FLIGHT + 2);
        let mut job = self
            .begin_job(JobKind::PhaseCalibration, frames, captures, hdr, conn)
            .await?;
        let _ = self.job_changed(emitter).await;
        self.job_step(&mut job, emitter, |tx| Command::CalibratePhase(frames, tx))
            .await?
            .map_err(phase_failed)
    }

    /// The reply of Calibrate; stores the fit in the state directory, if any.
    pub(super) async fn calibration_reply(
        &self,
        s: DarkStats,
        fit: PhotonTransferFit,
    ) -> CalibrationReply {
        let mut reply = CalibrationReply {
            frames: s.frames,
            mean_dn: s.mean_dn,
            read_noise_variance_dn2: s.read_noise_variance_dn2,
            fixed_pattern_sigma_dn: s.fixed_pattern_sigma_dn,
            gain_dn_per_electron: fit.gain_dn_per_electron,
            gain_se: fit.gain_se,
            ptc_read_variance_dn2: fit.read_variance_dn2,
            ptc_read_variance_se_dn2: fit.read_variance_se_dn2,
            reduced_chi2: fit.reduced_chi2,
            ptc_points: u32::try_from(fit.points).unwrap_or(u32::MAX),
            stored: None,
            store_error: None,
        };
        if let Some(dir) = self.info.state_dir.clone() {
            let record = CalibrationRecord::from_fit(
                &self.info.sensor.model,
                &self.info.device,
                &fit,
                s.fixed_pattern_sigma_dn,
                s.frames as usize,
            );
            let saved = tokio::task::spawn_blocking(move || calibration_store::save(&dir, record))
                .await
                .map_err(|e| std::io::Error::other(e.to_string()))
                .and_then(|r| r);
            // The fit is in use either way; a store that cannot be written
            // costs only the reload at the next start.
            match saved {
                Ok(path) => {
                    tracing::info!(path = %path.display(), "calibration stored");
                    reply.stored = Some(path.display().to_string());
                }
                Err(e) => {
                    tracing::warn!("storing the calibration: {e}");
                    reply.store_error = Some(e.to_string());
                }
            }
        }
        reply
    }

    /// Phase calibration needs the OPT8241-CDK's raw quads.
    pub(super) fn require_raw_quads(&self) -> Result<(), SdiError> {
        if self.info.backend != crate::backend::BackendName::Opt8241 {
            return Err(SdiError::Failed(format!(
                "phase calibration needs the OPT8241-CDK's raw quads; the backend is {} \
                 (set backend = \"opt8241\")",
                self.info.backend
            )));
        }
        Ok(())
    }

    /// The reply of CalibratePhase; stores the fit in the state directory, if any.
    pub(super) async fn phase_reply(&self, fit: PhaseFit) -> PhaseCalibrationReply {
        let mut reply = PhaseCalibrationReply {
            frames: fit.frames,
            angle_deg: fit.axis.angle_rad.to_degrees(),
            amplitude_dn: fit.amplitude_dn,
            coherence: fit.coherence,
            lights: self.info.lights.clone().unwrap_or_default(),
            stored: None,
            store_error: None,
        };
        tracing::info!(
            angle_deg = reply.angle_deg,
            amplitude_dn = fit.amplitude_dn,
            coherence = fit.coherence,
            "phase calibrated"
        );
        if let Some(dir) = self.info.state_dir.clone() {
            let record = PhaseRecord {
                model: self.info.sensor.model.clone(),
                serial: self.info.device.clone(),
                angle_rad: fit.axis.angle_rad,
                amplitude_dn: fit.amplitude_dn,
                coherence: fit.coherence,
                frames: fit.frames as usize,
            };
            let saved =
                tokio::task::spawn_blocking(move || calibration_store::save_phase(&dir, record))
                    .await
                    .map_err(|e| std::io::Error::other(e.to_string()))
                    .and_then(|r| r);
            match saved {
                Ok(path) => {
                    tracing::info!(path = %path.display(), "phase calibration stored");
                    reply.stored = Some(path.display().to_string());
                }
                Err(e) => {
                    tracing::warn!("storing the phase calibration: {e}");
                    reply.store_error = Some(e.to_string());
                }
            }
        }
        reply
    }
}
