//! The commands the frame loop takes between two captures.

use sdi_core::calibration::PhotonTransferFit;
use sdi_core::display::DisplayMap;
use sdi_core::mode::ModeId;
use tokio::sync::oneshot;

use super::{DarkStats, FrameLoop, FrameMark, JobError, SnapshotData};
use crate::backend::{BackendError, CaptureSettings};
use crate::frame_stream::{StreamError, StreamTarget};
use crate::phase_calibration::PhaseFit;
use crate::recorder::RecordingWriter;

/// The one-shot channel a command is answered on.
pub type Reply<T> = oneshot::Sender<T>;

/// Requests to the frame loop.
///
/// Every command that changes the picture (`SetMode`, `Configure`,
/// `SetDisplay`) applies between two captures and answers with the
/// [`FrameMark`] of the first frame under the new setting, once that frame's
/// output has been handed to the sinks (or at once, while the source is stalled).
pub enum Command {
    SetMode(ModeId, Reply<FrameMark>),
    /// Applies settings; replies with what the backend kept (a board may
    /// clamp), then with the first frame captured with them.
    Configure(
        CaptureSettings,
        Reply<Result<CaptureSettings, BackendError>>,
        Reply<FrameMark>,
    ),
    SetDisplay(DisplayMap, Reply<FrameMark>),
    CaptureDark(u32, Reply<Result<DarkStats, JobError>>),
    /// Photon-transfer calibration with this many frames per level; on
    /// success the separation mode's H uses the fitted gain and read variance.
    PhotonTransfer(u32, Reply<Result<PhotonTransferFit, JobError>>),
    /// Phase calibration with this many frames of LS1 alone; on success
    /// the board decodes with the fitted axis.
    CalibratePhase(u32, Reply<Result<PhaseFit, JobError>>),
    Snapshot(Reply<Option<SnapshotData>>),
    StartRecording(Box<RecordingWriter>, Reply<()>),
    /// Hands the recorder back; the caller finishes it (off this thread).
    StopRecording(Reply<Option<RecordingWriter>>),
    /// Writes every output from now on into this pipe or socket, for the
    /// bus connection named (its unique name).
    StreamFrames(StreamTarget, String, Reply<Result<(), StreamError>>),
    /// The bus connection named left the bus: its streams end.
    PeerLeft(String),
    /// Ends the running job (its call gets [`JobError::Cancelled`]); none: nothing.
    CancelJob,
    Shutdown,
}

impl FrameLoop {
    pub(super) fn handle(&mut self, cmd: Command) {
        match cmd {
            Command::SetMode(mode, reply) => {
                if mode != self.mode {
                    self.mode = mode;
                    self.rebuild_pipeline();
                    self.backend.set_mode(mode);
                }
                self.await_first_frame(reply);
            }
            Command::Configure(settings, reply, first) => {
                let applied = self
                    .backend
                    .configure(&settings)
                    .map(|()| self.backend.settings());
                let _ = reply.send(applied);
                self.await_first_frame(first);
            }
            Command::SetDisplay(d, reply) => {
                self.display = d;
                self.await_first_frame(reply);
            }
            Command::CaptureDark(_, reply) if self.job.is_some() => {
                let _ = reply.send(Err(JobError::AlreadyRunning));
            }
            Command::CaptureDark(frames, reply) => {
                self.next_job();
                self.start_dark(frames, reply);
            }
            Command::PhotonTransfer(_, reply) if self.job.is_some() => {
                let _ = reply.send(Err(JobError::AlreadyRunning));
            }
            Command::PhotonTransfer(frames, reply) => {
                self.next_job();
                self.start_photon_transfer(frames, reply);
            }
            Command::CalibratePhase(_, reply) if self.job.is_some() => {
                let _ = reply.send(Err(JobError::AlreadyRunning));
            }
            Command::CalibratePhase(frames, reply) => {
                self.next_job();
                self.start_phase(frames, reply);
            }
            Command::Snapshot(reply) if !self.lights.is_settled() => {
                // lights off (nobody watched) or just switched on
                self.pending_snapshots.push(reply);
            }
            Command::Snapshot(reply) => {
                let _ = reply.send(self.snapshot());
            }
            Command::StartRecording(rec, reply) => {
                if let Some((frames, dn)) = &self.dark {
                    rec.push_dark(*frames, dn);
                }
                // a replaced recorder finishes on its own thread
                drop(self.recorder.replace(*rec));
                let _ = reply.send(());
            }
            Command::StopRecording(reply) => {
                let _ = reply.send(self.recorder.take());
            }
            Command::StreamFrames(target, owner, reply) => {
                let _ = reply.send(self.fanout.streams().open(target, &owner));
            }
            Command::PeerLeft(owner) => self.fanout.streams().close_owner(&owner),
            Command::CancelJob => {
                if let Some(job) = self.job.take() {
                    job.end_with(&mut *self.backend, JobError::Cancelled);
                }
            }
            Command::Shutdown => {}
        }
    }
}
