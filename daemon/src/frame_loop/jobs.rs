//! Jobs running instead of the mode pipeline: the dark frame, photon
//! transfer and the phase calibration, with their progress and results.

use sdi_core::calibration::PhotonTransferFit;
use sdi_core::modulation::Illumination;
use sdi_core::quad_phase::{PhaseAxis, PhaseError};
use sdi_core::sensor::SkellamMixing;
use sdi_core::{Frame, Image};

use super::{FrameLoop, Reply};
use crate::backend::{Backend, BackendError};
use crate::dark_capture::{DarkCapture, DarkJob, NoUsablePixels};
use crate::job::Running;
use crate::phase_calibration::{PhaseFit, PhaseJob};
use crate::photon_transfer::{PtcError, PtcJob};

/// Statistics of a dark-frame capture (computed in core).
pub use sdi_core::dark_frame::DarkStats;

/// Why a dark-frame capture or calibration gave no result.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// A second dark capture or calibration while one runs.
    #[error("a dark-frame capture or calibration is already running")]
    AlreadyRunning,
    #[error(transparent)]
    Backend(#[from] BackendError),
    #[error(transparent)]
    NoUsablePixels(#[from] NoUsablePixels),
    #[error(transparent)]
    PhotonTransfer(#[from] PtcError),
    #[error(transparent)]
    Phase(#[from] PhaseError),
    /// The light rig cannot light LS1 alone (the board's own output).
    #[error("the light sources cannot light LS1 alone: {0}")]
    LightsRefused(String),
    /// The job finished but its capture settings could not be put back.
    #[error("restoring the capture settings: {0}")]
    Restore(#[source] BackendError),
    /// Ended by [`Command::CancelJob`]; its settings were put back.
    #[error("cancelled")]
    Cancelled,
}

/// How far the running job got: a number per job started (so a reader
/// tells a new job's count from the last one's) and its frames so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct JobProgress {
    pub job: u64,
    pub frames: u32,
}

/// The job running instead of the mode pipeline, with its reply.
pub(super) enum ActiveJob {
    Dark(Running<DarkJob>, Reply<Result<DarkStats, JobError>>),
    PhotonTransfer(Running<PtcJob>, Reply<Result<PhotonTransferFit, JobError>>),
    Phase(Running<PhaseJob>, Reply<Result<PhaseFit, JobError>>),
}

impl ActiveJob {
    pub(super) fn illumination(&self, carrier_hz: f64) -> Illumination {
        match self {
            Self::Dark(run, _) => run.illumination(carrier_hz),
            Self::PhotonTransfer(run, _) => run.illumination(carrier_hz),
            Self::Phase(run, _) => run.illumination(carrier_hz),
        }
    }

    /// The capture failed: puts the settings back and replies with `e`.
    pub(super) fn fail(self, backend: &mut dyn Backend, e: BackendError) {
        self.end_with(backend, e.into());
    }

    /// Puts the settings back and replies with `e` (a failure, a cancel).
    pub(super) fn end_with(self, backend: &mut dyn Backend, e: JobError) {
        match self {
            Self::Dark(run, reply) => {
                let _ = run.end(backend);
                let _ = reply.send(Err(e));
            }
            Self::PhotonTransfer(run, reply) => {
                let _ = run.end(backend);
                let _ = reply.send(Err(e));
            }
            Self::Phase(run, reply) => {
                let _ = backend.measure_phase(false);
                let _ = run.end(backend);
                let _ = reply.send(Err(e));
            }
        }
    }

    /// Frames the job has taken so far.
    pub(super) fn progress(&self) -> u32 {
        match self {
            Self::Dark(run, _) => run.progress(),
            Self::PhotonTransfer(run, _) => run.progress(),
            Self::Phase(run, _) => run.progress(),
        }
    }
}

impl FrameLoop {
    pub(super) fn set_dark(&mut self, frames: u32, dn: Image<f32>) {
        self.pipeline.set_dark_frame(Some(dn.clone()));
        if let Some(rec) = &self.recorder {
            rec.push_dark(frames, &dn);
        }
        self.dark = Some((frames, dn));
        self.calibration.dark_frames = frames;
    }

    /// Starts averaging `frames` dark frames; a backend that refuses the
    /// job's settings answers at once.
    pub(super) fn start_dark(&mut self, frames: u32, reply: Reply<Result<DarkStats, JobError>>) {
        let (w, h) = (self.backend.sensor().width, self.backend.sensor().height);
        match Running::start(DarkJob::new(frames, w, h), &mut *self.backend) {
            Ok(run) => self.job = Some(ActiveJob::Dark(run, reply)),
            Err(e) => {
                let _ = reply.send(Err(e.into()));
            }
        }
    }

    /// Starts the photon-transfer calibration, `frames` frames per level,
    /// with the dark frame held; a backend that refuses the first level's
    /// settings answers at once.
    pub(super) fn start_photon_transfer(
        &mut self,
        frames: u32,
        reply: Reply<Result<PhotonTransferFit, JobError>>,
    ) {
        let (w, h) = (self.backend.sensor().width, self.backend.sensor().height);
        let job = PtcJob::new(
            self.backend.settings(),
            frames,
            self.dark.as_ref().map(|d| d.1.clone()),
            w,
            h,
        );
        match Running::start(job, &mut *self.backend) {
            Ok(run) => self.job = Some(ActiveJob::PhotonTransfer(run, reply)),
            Err(e) => {
                let _ = reply.send(Err(e.into()));
            }
        }
    }

    /// Starts the phase calibration: `frames` frames of LS1 alone; a
    /// backend without phase quads answers at once.
    pub(super) fn start_phase(&mut self, frames: u32, reply: Reply<Result<PhaseFit, JobError>>) {
        let started = self
            .backend
            .measure_phase(true)
            .and_then(|()| Running::start(PhaseJob::new(frames), &mut *self.backend));
        match started {
            Ok(run) => self.job = Some(ActiveJob::Phase(run, reply)),
            Err(e) => {
                let _ = self.backend.measure_phase(false);
                let _ = reply.send(Err(e.into()));
            }
        }
    }

    /// Numbers the job about to start; its progress counts from 0.
    pub(super) fn next_job(&mut self) {
        self.job_progress.send_modify(|p| {
            p.job += 1;
            p.frames = 0;
        });
    }

    /// Decodes with `axis` from now on (a stored or fitted phase axis).
    pub fn set_phase_axis(&mut self, axis: PhaseAxis) -> Result<(), BackendError> {
        self.backend.set_phase_axis(Some(axis))
    }

    /// Feeds the running job a frame; applies and answers its result once done.
    pub(super) fn job_step(&mut self, frame: &Frame) {
        let Some(job) = self.job.take() else {
            return;
        };
        let backend = &mut *self.backend;
        match job {
            ActiveJob::Dark(mut run, reply) => match run.feed(frame, backend) {
                Ok(None) => self.job = Some(ActiveJob::Dark(run, reply)),
                Ok(Some(done)) => {
                    let _ = run.end(backend);
                    let r = done
                        .map(|capture| self.finish_dark(capture))
                        .map_err(JobError::from);
                    let _ = reply.send(r);
                }
                Err(e) => ActiveJob::Dark(run, reply).fail(backend, e),
            },
            ActiveJob::PhotonTransfer(mut run, reply) => match run.feed(frame, backend) {
                Ok(None) => self.job = Some(ActiveJob::PhotonTransfer(run, reply)),
                Ok(Some(r)) => {
                    let restored = run.end(backend);
                    self.finish_photon_transfer(r, restored, reply);
                }
                Err(e) => ActiveJob::PhotonTransfer(run, reply).fail(backend, e),
            },
            ActiveJob::Phase(mut run, reply) => {
                // A rig that cannot light LS1 alone would leave both lit:
                // the fit would be wrong, not merely noisy.
                if let Some(refused) = backend.lights().and_then(|l| l.refused) {
                    let _ = backend.measure_phase(false);
                    let _ = run.end(backend);
                    let _ = reply.send(Err(JobError::LightsRefused(refused)));
                    return;
                }
                run.job_mut().offer(backend.take_phase_sums());
                match run.feed(frame, backend) {
                    Ok(None) => self.job = Some(ActiveJob::Phase(run, reply)),
                    Ok(Some(r)) => {
                        let _ = backend.measure_phase(false);
                        let restored = run.end(backend);
                        let r = match (r, restored) {
                            (Err(e), _) => Err(e.into()),
                            (Ok(_), Err(e)) => Err(JobError::Restore(e)),
                            (Ok(fit), Ok(())) => backend
                                .set_phase_axis(Some(fit.axis))
                                .map(|()| fit)
                                .map_err(JobError::from),
                        };
                        let _ = reply.send(r);
                    }
                    Err(e) => ActiveJob::Phase(run, reply).fail(backend, e),
                }
            }
        }
    }

    /// Uses a successful fit for H and replies.
    fn finish_photon_transfer(
        &mut self,
        r: Result<PhotonTransferFit, PtcError>,
        restored: Result<(), BackendError>,
        reply: Reply<Result<PhotonTransferFit, JobError>>,
    ) {
        if let Ok(fit) = &r {
            self.set_gain(SkellamMixing::new(
                fit.gain_dn_per_electron,
                fit.read_variance_dn2.max(0.0),
            ));
        }
        let r = match (r, restored) {
            (Ok(_), Err(e)) => Err(JobError::Restore(e)),
            (r, _) => r.map_err(JobError::from),
        };
        let _ = reply.send(r);
    }

    /// Uses `h` (from a calibration) in the separation mode from now on.
    pub fn set_gain(&mut self, h: SkellamMixing) {
        self.separation.h = h;
        self.rebuild_pipeline();
    }

    /// Holds the captured dark frame and publishes its statistics.
    fn finish_dark(&mut self, capture: DarkCapture) -> DarkStats {
        let stats = capture.stats;
        self.set_dark(stats.frames, capture.dark_dn);
        let var_t = stats.read_noise_variance_dn2;
        self.calibration.read_noise_variance_dn2 = var_t.is_finite().then_some(var_t);
        self.calibration.fixed_pattern_sigma_dn = Some(stats.fixed_pattern_sigma_dn);
        self.calibration_tx.send_replace(self.calibration.clone());
        stats
    }
}
