//! The frame loop: a dedicated thread that captures, processes and hands
//! frames on. It never waits on D-Bus, logging or disk: commands arrive on a
//! channel polled between frames, replies go out on one-shot channels, and
//! outputs and recordings sit behind bounded non-blocking queues.

use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::separation::{LiveMethod, LiveSeparatorConfig};
use sdi_core::{Frame, Image};
use tokio::sync::{oneshot, watch};

use crate::backend::pacer::Pacer;
use crate::backend::{Backend, BackendError, CaptureSettings};
use crate::cause_log::{repeats, CauseLog};
use crate::dark_capture::{DarkCapture, DarkJob, NoUsablePixels};
use crate::frame_stream::{FrameStreams, StreamError, StreamTarget};
use crate::job::{Running, Settling};
use crate::monotonic::{monotonic_now_us, MonotonicClock};
use crate::phase_calibration::{PhaseFit, PhaseJob};
use crate::photon_transfer::{PtcError, PtcJob};
use crate::publish_clock::PublishClock;
use crate::recorder::RecordingWriter;
use crate::sink::output::Output;
use crate::stats::{LoopStats, StatsWindow};
use sdi_core::calibration::PhotonTransferFit;
use sdi_core::display::DisplayMap;
use sdi_core::mode::{build_pipeline, ModeOutput, Pipeline, PipelineConfig};
use sdi_core::quad_phase::{PhaseAxis, PhaseError};
use sdi_core::sensor::SkellamMixing;
use sdi_recording::Calibration;

/// Statistics of a dark-frame capture (computed in core).
pub use sdi_core::dark_frame::DarkStats;

/// The latest processed frame, for snapshots.
pub struct SnapshotData {
    pub mode: ModeId,
    pub output: Arc<ModeOutput>,
    pub display: DisplayMap,
}

pub type Reply<T> = oneshot::Sender<T>;

/// Longest a command waiting for a frame waits for a paced source's frame
/// clock; beyond it the frame is captured at once (slow frame rates).
const MAX_COMMAND_WAIT: Duration = Duration::from_millis(100);
/// Wait before trying a failed capture again.
const STALL_RETRY: Duration = Duration::from_millis(200);
/// Longest calls waiting for a frame (a setting change's mark, a snapshot)
/// wait while the source sends nothing yet has not failed (the board gives
/// up after its 2 s frame wait, in slices of 100 ms: [`BackendError::NotYet`]):
/// then they are answered as during a stall. Longer than the board's
/// slowest frame period (350 ms at 2.86 Hz), so a slow board in step
/// answers them with its frame; shorter than issue 31's 1 s by a slice
/// and a margin.
const SILENT_CALL_WAIT: Duration = Duration::from_millis(500);

/// Why the source stalled, as Stats says it (and the key of its log line).
fn stall_cause(e: &BackendError) -> &'static str {
    match e {
        BackendError::EndOfStream => "end of recording",
        BackendError::Unavailable(_) => "device unavailable",
        BackendError::OutOfRange(_) | BackendError::Failed(_) => "capture failing",
        // never a stall (`FrameLoop::run`); named for completeness
        BackendError::NotYet => "no frame yet",
    }
}

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

/// The first frame produced under a new setting: every published output with
/// `sequence >= self.sequence` (and timestamp `>= self.timestamp_us`) was
/// captured under it, every one before under the old setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameMark {
    /// sdid's frame sequence number (one per capture, never reset).
    pub sequence: u64,
    /// Capture timestamp, microseconds: the V4L2 buffer timestamp readers see.
    /// 0 when the source delivers no frames (the mark is then the next one).
    pub timestamp_us: u64,
}

/// A reply waiting for the first output under a new setting.
struct PendingMark {
    reply: Reply<FrameMark>,
    /// Set at the first capture after the setting was applied.
    captured: Option<FrameMark>,
}

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

/// The job running instead of the mode pipeline, with its reply.
enum ActiveJob {
    Dark(Running<DarkJob>, Reply<Result<DarkStats, JobError>>),
    PhotonTransfer(Running<PtcJob>, Reply<Result<PhotonTransferFit, JobError>>),
    Phase(Running<PhaseJob>, Reply<Result<PhaseFit, JobError>>),
}

impl ActiveJob {
    fn illumination(&self, carrier_hz: f64) -> Illumination {
        match self {
            Self::Dark(run, _) => run.illumination(carrier_hz),
            Self::PhotonTransfer(run, _) => run.illumination(carrier_hz),
            Self::Phase(run, _) => run.illumination(carrier_hz),
        }
    }

    /// The capture failed: puts the settings back and replies with `e`.
    fn fail(self, backend: &mut dyn Backend, e: BackendError) {
        self.end_with(backend, e.into());
    }

    /// Puts the settings back and replies with `e` (a failure, a cancel).
    fn end_with(self, backend: &mut dyn Backend, e: JobError) {
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
    fn progress(&self) -> u32 {
        match self {
            Self::Dark(run, _) => run.progress(),
            Self::PhotonTransfer(run, _) => run.progress(),
            Self::Phase(run, _) => run.progress(),
        }
    }
}

pub struct FrameLoop {
    backend: Box<dyn Backend>,
    pipeline: Box<dyn Pipeline>,
    mode: ModeId,
    display: DisplayMap,
    output: Output,
    /// Clients' frame streams (`StreamFrames`).
    streams: FrameStreams,
    recorder: Option<RecordingWriter>,
    dark: Option<(u32, Image<f32>)>,
    calibration: Calibration,
    /// Dark capture or calibration running instead of the pipeline.
    job: Option<ActiveJob>,
    last: Option<Arc<ModeOutput>>,
    stats: StatsWindow,
    stats_tx: watch::Sender<LoopStats>,
    calibration_tx: watch::Sender<Calibration>,
    /// Estimator and H of the separation mode.
    separation: LiveSeparatorConfig,
    /// Maps a device's own frame clock onto CLOCK_MONOTONIC, increasing
    /// when the device restarts it.
    clock: MonotonicClock,
    /// The one timestamp of each frame and "no signal" card published.
    stamps: PublishClock,
    /// Snapshots asked for while the lights were off: answered from the
    /// first output of two consecutive lit captures.
    pending_snapshots: Vec<Reply<Option<SnapshotData>>>,
    /// Whether the mode's illumination (not dark) has been on long enough
    /// for a capture to be wholly lit.
    lights: Settling,
    /// Sequence number of the last capture (the first is 1).
    sequence: u64,
    /// Setting changes waiting for their first published frame.
    pending_marks: Vec<PendingMark>,
    /// The running (or last) job's number and the frames it has taken.
    job_progress: watch::Sender<JobProgress>,
}

/// Whether the light sources must be on: someone watches the output (or
/// the sink cannot tell: v4l2loopback 0.12.x, y4m), a recording runs, or a
/// snapshot waits. Dark calibration runs dark anyway.
pub fn lights_needed(watchers: Option<u32>, recording: bool, snapshot_pending: bool) -> bool {
    watchers != Some(0) || recording || snapshot_pending
}

impl FrameLoop {
    pub fn new(
        backend: Box<dyn Backend>,
        mode: ModeId,
        display: DisplayMap,
        output: Output,
        stats_tx: watch::Sender<LoopStats>,
        calibration_tx: watch::Sender<Calibration>,
    ) -> Self {
        let separation = LiveSeparatorConfig {
            h: backend.sensor().skellam(),
            ..LiveSeparatorConfig::default()
        };
        let pipeline = build_pipeline(
            mode,
            PipelineConfig {
                separation,
                ..PipelineConfig::default()
            },
        );
        Self {
            backend,
            pipeline,
            mode,
            display,
            output,
            streams: FrameStreams::default(),
            recorder: None,
            dark: None,
            calibration: Calibration::default(),
            job: None,
            last: None,
            stats: StatsWindow::new(),
            stats_tx,
            calibration_tx,
            separation,
            clock: MonotonicClock::default(),
            stamps: PublishClock::default(),
            pending_snapshots: Vec::new(),
            lights: Settling::changed(),
            sequence: 0,
            pending_marks: Vec::new(),
            job_progress: watch::Sender::new(JobProgress::default()),
        }
    }

    /// The running (or last) job's progress.
    pub fn job_progress(&self) -> watch::Receiver<JobProgress> {
        self.job_progress.subscribe()
    }

    /// Selects the separation mode's estimator (M3 by default).
    pub fn with_separation(mut self, method: LiveMethod) -> Self {
        self.separation.method = method;
        self.rebuild_pipeline();
        self
    }

    /// A fresh pipeline for the current mode, with the dark frame and H held.
    fn rebuild_pipeline(&mut self) {
        self.pipeline = build_pipeline(
            self.mode,
            PipelineConfig {
                dark_frame_dn: self.dark.as_ref().map(|d| d.1.clone()),
                separation: self.separation,
                ..PipelineConfig::default()
            },
        );
    }

    /// Runs until `Shutdown` or until every command sender is gone; returns
    /// the recorder, if any, for the caller to finish (off this thread).
    pub fn run(mut self, commands: Receiver<Command>) -> Option<RecordingWriter> {
        let (w, h) = (self.backend.sensor().width, self.backend.sensor().height);
        let mut frame = Frame::new(w, h);
        let mut stalled = false;
        let mut stall_log = CauseLog::default();
        let mut pacer = Pacer::new();
        // After a failed capture, the next attempt is not before this.
        let mut retry_at = Instant::now();
        // When the source last delivered a frame (or the loop started).
        let mut last_frame_at = Instant::now();
        loop {
            if !self.wait_turn(&commands, &pacer, retry_at) {
                return self.recorder.take();
            }
            let lit = self.lights_wanted();
            let illumination = self.illumination(lit);
            let paced = self.backend.paced_rate_hz();
            let captured_at = Instant::now();
            let captured_at_us = monotonic_now_us();
            // The first frame after a stall publishes Stats at once: a client
            // must not read "device unavailable" for half a window more.
            let resumed = match self.backend.capture(&illumination, &mut frame) {
                Ok(()) => std::mem::replace(&mut stalled, false),
                Err(BackendError::NotYet) => {
                    // No frame within the backend's slice: commands are
                    // handled, and the capture goes on at once.
                    if last_frame_at.elapsed() >= SILENT_CALL_WAIT {
                        self.answer_while_silent();
                    }
                    continue;
                }
                Err(e) => {
                    if !stalled {
                        // Once per stall, and once per cause in a while: a
                        // flapping device must not flood the log.
                        if let Some(quiet) = stall_log.admit(stall_cause(&e)) {
                            tracing::warn!("backend: {e}; showing no-signal{}", repeats(quiet));
                        }
                        stalled = true;
                    }
                    self.capture_failed(e);
                    retry_at = Instant::now() + STALL_RETRY;
                    continue;
                }
            };
            last_frame_at = Instant::now();
            if let Some(rate_hz) = paced {
                pacer.tick(rate_hz, captured_at);
            }
            let t0 = Instant::now();
            self.stamp(&mut frame, paced.map(|_| captured_at_us));
            if lit {
                self.lights.capture();
            } else {
                self.lights.change();
            }
            self.process(&frame);
            if self.stats.frame(t0.elapsed()) || resumed {
                self.publish_stats();
            }
        }
    }

    /// Whether the mode's light sources are to be on for the next capture
    /// (never during a job: it drives them itself).
    fn lights_wanted(&mut self) -> bool {
        self.job.is_none()
            && lights_needed(
                self.output
                    .watchers()
                    .map(|n| n.saturating_add(self.streams.len() as u32)),
                self.recorder.is_some(),
                !self.pending_snapshots.is_empty(),
            )
    }

    /// How the sources are driven for the next capture: as the job asks,
    /// as the mode asks when `lit`, else dark.
    fn illumination(&self, lit: bool) -> Illumination {
        let carrier_hz = self.backend.settings().modulation_hz;
        if let Some(job) = &self.job {
            job.illumination(carrier_hz)
        } else if lit {
            // Numbered as the frame will be: the two-shot pipeline pairs by it.
            self.mode.illumination(self.sequence + 1, carrier_hz)
        } else {
            Illumination::dark(carrier_hz)
        }
    }

    /// The capture failed: the job fails, waiting calls are answered, and
    /// the "no signal" card goes out with Stats saying why.
    fn capture_failed(&mut self, e: BackendError) {
        self.stats.stalled(stall_cause(&e));
        if let Some(job) = self.job.take() {
            job.fail(&mut *self.backend, e);
        }
        self.lights.change();
        self.answer_pending_snapshots();
        self.answer_marks_while_stalled();
        // No output pairs a frame from before the card with one
        // after it (it would carry a stamp older than the card's).
        self.pipeline.reset();
        let card_us = self.stamps.no_signal(monotonic_now_us());
        self.output.send_no_signal(card_us);
        self.stats_tx.send_replace(self.stats.current.clone());
    }

    /// The source has sent nothing for [`SILENT_CALL_WAIT`] but not failed:
    /// the calls waiting for a frame are answered as while stalled, and
    /// nothing else changes (no card: that waits for the failure).
    fn answer_while_silent(&mut self) {
        self.answer_pending_snapshots();
        self.answer_marks_while_stalled();
    }

    /// Gives the captured frame its published timestamp and sdid's sequence
    /// number. `paced_at_us`: when this loop captured a paced source.
    fn stamp(&mut self, frame: &mut Frame, paced_at_us: Option<u64>) {
        let period_us = (1e6 / self.backend.settings().frame_rate_hz.max(1e-3)) as u64;
        let now_us = monotonic_now_us();
        // A paced source was captured when this loop's clock said (or a
        // command asked): that moment is its stamp, passed through. A
        // device's own clock is mapped onto the monotonic one.
        let captured_us = match paced_at_us {
            Some(at_us) => at_us,
            None => self.clock.map(frame.timestamp_us, period_us, now_us),
        };
        frame.timestamp_us = self.stamps.frame(captured_us, now_us);
        self.sequence = self.next_sequence(frame.sequence);
        frame.sequence = self.sequence;
        self.mark_capture(frame);
    }

    /// Records the frame and feeds it to the job or the mode pipeline,
    /// publishing the output and answering the calls that waited for it.
    fn process(&mut self, frame: &Frame) {
        if let Some(dark) = self.backend.take_dark_frame() {
            self.set_dark(dark.0, dark.1);
        }
        if let (Some(rec), None) = (&self.recorder, &self.job) {
            rec.push_frame(self.mode.name(), frame);
        }
        if self.job.is_some() {
            self.job_step(frame);
            if let Some(frames) = self.job.as_ref().map(ActiveJob::progress) {
                self.job_progress
                    .send_if_modified(|p| std::mem::replace(&mut p.frames, frames) != frames);
            }
            self.answer_marks(u64::MAX);
        } else if let Some(out) = self.pipeline.process(frame) {
            let out = Arc::new(out.clone());
            self.output.send(out.clone(), self.display);
            self.streams.send(&out, self.display, self.mode);
            let published = out.sequence;
            self.last = Some(out);
            self.answer_marks(published);
            if self.lights.is_settled() {
                self.answer_pending_snapshots();
            }
        }
    }

    /// Sends Stats with the drop counters of the output and the recorder.
    fn publish_stats(&mut self) {
        let mut s = self.stats.current.clone();
        s.counters.dropped_view = self.output.dropped();
        s.counters.dropped_recording = self.recorder.as_ref().map_or(0, |r| {
            r.counters()
                .dropped
                .load(std::sync::atomic::Ordering::Relaxed)
        });
        self.stats_tx.send_replace(s);
    }

    /// Handles commands until the next capture is due: at once for a source
    /// with its own frame clock, when the pacer says for the others, and at
    /// once when a command waits for a frame (a setting change, a snapshot)
    /// and the clock is more than [`MAX_COMMAND_WAIT`] away, so no call waits
    /// for a slow frame clock while at 10 Hz and faster commands add no
    /// frames (the published rate stays the configured one). Not before
    /// `retry_at` (after a failed capture) unless a command waits. False on
    /// `Shutdown` or when every sender is gone.
    fn wait_turn(
        &mut self,
        commands: &Receiver<Command>,
        pacer: &Pacer,
        retry_at: Instant,
    ) -> bool {
        loop {
            loop {
                match commands.try_recv() {
                    Ok(Command::Shutdown) | Err(TryRecvError::Disconnected) => return false,
                    Ok(cmd) => self.handle(cmd),
                    Err(TryRecvError::Empty) => break,
                }
            }
            let waiting = !self.pending_marks.is_empty() || !self.pending_snapshots.is_empty();
            let now = Instant::now();
            let clock = self
                .backend
                .paced_rate_hz()
                .map_or(Duration::ZERO, |rate_hz| pacer.remaining(rate_hz, now));
            if waiting && clock > MAX_COMMAND_WAIT {
                return true;
            }
            let due = clock.max(if waiting {
                Duration::ZERO
            } else {
                retry_at.saturating_duration_since(now)
            });
            if due.is_zero() {
                return true;
            }
            match commands.recv_timeout(due) {
                Ok(Command::Shutdown) | Err(RecvTimeoutError::Disconnected) => return false,
                Ok(cmd) => self.handle(cmd),
                Err(RecvTimeoutError::Timeout) => return true,
            }
        }
    }

    /// The latest output, with the mode and display it was made for.
    fn snapshot(&self) -> Option<SnapshotData> {
        self.last.clone().map(|output| SnapshotData {
            mode: self.mode,
            output,
            display: self.display,
        })
    }

    /// sdid's number for the frame just captured: one more than the last,
    /// except that a replayed frame keeps its recorded parity (two-shot A/B).
    fn next_sequence(&self, backend_sequence: u64) -> u64 {
        let next = self.sequence + 1;
        if self.backend.replays() {
            next + ((next ^ backend_sequence) & 1)
        } else {
            next
        }
    }

    /// Notes the first capture under each pending setting change.
    fn mark_capture(&mut self, frame: &Frame) {
        for p in self
            .pending_marks
            .iter_mut()
            .filter(|p| p.captured.is_none())
        {
            p.captured = Some(FrameMark {
                sequence: frame.sequence,
                timestamp_us: frame.timestamp_us,
            });
        }
    }

    /// Answers the setting changes whose first frame is in an output up to
    /// sequence `published` (`u64::MAX`: captured, and no output follows,
    /// as during a dark-frame or calibration job).
    fn answer_marks(&mut self, published: u64) {
        let (done, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.pending_marks)
            .into_iter()
            .partition(|p| p.captured.is_some_and(|m| m.sequence <= published));
        self.pending_marks = waiting;
        for p in done {
            if let Some(mark) = p.captured {
                let _ = p.reply.send(mark);
            }
        }
    }

    /// While the source delivers nothing, setting changes return at once with
    /// the sequence number the next frame will carry.
    fn answer_marks_while_stalled(&mut self) {
        let next = FrameMark {
            sequence: self.sequence + 1,
            timestamp_us: 0,
        };
        for p in std::mem::take(&mut self.pending_marks) {
            let _ = p.reply.send(p.captured.unwrap_or(next));
        }
    }

    fn await_first_frame(&mut self, reply: Reply<FrameMark>) {
        self.pending_marks.push(PendingMark {
            reply,
            captured: None,
        });
    }

    /// Answers every snapshot waiting for lit frames with the latest output.
    fn answer_pending_snapshots(&mut self) {
        for reply in std::mem::take(&mut self.pending_snapshots) {
            let _ = reply.send(self.snapshot());
        }
    }

    fn set_dark(&mut self, frames: u32, dn: Image<f32>) {
        self.pipeline.set_dark_frame(Some(dn.clone()));
        if let Some(rec) = &self.recorder {
            rec.push_dark(frames, &dn);
        }
        self.dark = Some((frames, dn));
        self.calibration.dark_frames = frames;
    }

    fn handle(&mut self, cmd: Command) {
        match cmd {
            Command::SetMode(mode, reply) => {
                if mode != self.mode {
                    self.mode = mode;
                    self.rebuild_pipeline();
                    self.backend.set_mode(mode);
                    self.output.set_mode(mode);
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
                let _ = reply.send(self.streams.open(target, &owner));
            }
            Command::PeerLeft(owner) => self.streams.close_owner(&owner),
            Command::CancelJob => {
                if let Some(job) = self.job.take() {
                    job.end_with(&mut *self.backend, JobError::Cancelled);
                }
            }
            Command::Shutdown => {}
        }
    }

    /// Starts averaging `frames` dark frames; a backend that refuses the
    /// job's settings answers at once.
    fn start_dark(&mut self, frames: u32, reply: Reply<Result<DarkStats, JobError>>) {
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
    fn start_photon_transfer(
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
    fn start_phase(&mut self, frames: u32, reply: Reply<Result<PhaseFit, JobError>>) {
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
    fn next_job(&mut self) {
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
    fn job_step(&mut self, frame: &Frame) {
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

#[cfg(test)]
mod tests {
    use super::{lights_needed, Command, FrameLoop, FrameMark};
    use crate::backend::sim::SimBackend;
    use crate::backend::{Backend, BackendError, CaptureSettings};
    use crate::monotonic::monotonic_now_us;
    use crate::sink::output::Output;
    use crate::sink::{Sink, SinkError, SinkInfo};
    use sdi_core::display::DisplayMap;
    use sdi_core::mode::{ModeId, ModeOutput};
    use sdi_core::modulation::Illumination;
    use sdi_core::sensor::{SensorParams, SensorPreset};
    use sdi_core::Frame;
    use std::sync::{Arc, Mutex};
    use std::time::{Duration, Instant};

    /// The simulator, failing the capture attempts marked in `fails` (a
    /// source that pauses) and taking `first_capture` over its first frame;
    /// or, when `silent`, a device with its own frame clock that never
    /// sends a frame nor fails ([`BackendError::NotYet`] after a short slice).
    struct Scripted {
        sim: SimBackend,
        fails: Vec<bool>,
        attempt: usize,
        first_capture: Option<Duration>,
        silent: bool,
    }

    impl Backend for Scripted {
        fn kind(&self) -> crate::backend::BackendName {
            self.sim.kind()
        }
        fn device(&self) -> String {
            self.sim.device()
        }
        fn sensor(&self) -> &SensorParams {
            self.sim.sensor()
        }
        fn settings(&self) -> CaptureSettings {
            self.sim.settings()
        }
        fn configure(&mut self, s: &CaptureSettings) -> Result<(), BackendError> {
            self.sim.configure(s)
        }
        fn paced_rate_hz(&self) -> Option<f64> {
            self.sim.paced_rate_hz().filter(|_| !self.silent)
        }
        fn capture(&mut self, ill: &Illumination, frame: &mut Frame) -> Result<(), BackendError> {
            if self.silent {
                std::thread::sleep(Duration::from_millis(10));
                return Err(BackendError::NotYet);
            }
            self.attempt += 1;
            if self.fails.get(self.attempt - 1).copied().unwrap_or(false) {
                return Err(BackendError::Unavailable("paused".into()));
            }
            if let Some(took) = self.first_capture.take() {
                std::thread::sleep(took);
            }
            self.sim.capture(ill, frame)
        }
    }

    /// What a sink was given: (is the card, timestamp, CLOCK_MONOTONIC at the write).
    type Written = Arc<Mutex<Vec<(bool, u64, u64)>>>;

    struct Seen(Written);

    impl Sink for Seen {
        fn info(&self) -> SinkInfo {
            SinkInfo {
                kind: crate::sink::SinkKindName::Y4m,
                device: String::new(),
                format: String::new(),
                width: 0,
                height: 0,
            }
        }
        fn write(&mut self, out: &ModeOutput, _: &DisplayMap) -> Result<(), SinkError> {
            let now_us = monotonic_now_us();
            self.0
                .lock()
                .unwrap()
                .push((false, out.timestamp_us, now_us));
            Ok(())
        }
        fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
            let now_us = monotonic_now_us();
            self.0.lock().unwrap().push((true, timestamp_us, now_us));
            Ok(())
        }
    }

    /// A 16x8 simulator at 200 Hz.
    fn sim(mode: ModeId) -> SimBackend {
        let mut p = SensorPreset::TiOpt8241.params();
        p.width = 16;
        p.height = 8;
        p.frame_rate_hz = 200.0;
        SimBackend::new(p, mode, 1, None).unwrap()
    }

    /// The frame loop over `backend`, running on its own thread, and what
    /// its sink is given.
    fn spawn_loop(
        backend: Scripted,
        mode: ModeId,
    ) -> (
        std::sync::mpsc::Sender<Command>,
        std::thread::JoinHandle<Option<crate::recorder::RecordingWriter>>,
        Written,
    ) {
        let written = Written::default();
        let output = Output::spawn(Box::new(Seen(written.clone()))).unwrap();
        let (stats_tx, _stats) = tokio::sync::watch::channel(Default::default());
        let (cal_tx, _cal) = tokio::sync::watch::channel(Default::default());
        let fl = FrameLoop::new(
            Box::new(backend),
            mode,
            DisplayMap::default(),
            output,
            stats_tx,
            cal_tx,
        );
        let (tx, rx) = std::sync::mpsc::channel();
        (tx, std::thread::spawn(move || fl.run(rx)), written)
    }

    /// Runs the frame loop in `mode` over a source that fails the attempts
    /// marked in `fails` until the sink has `writes` writes; returns them.
    fn published(mode: ModeId, fails: Vec<bool>, writes: usize) -> Vec<(bool, u64, u64)> {
        let backend = Scripted {
            sim: sim(mode),
            fails,
            attempt: 0,
            // A slow first capture: later frames must not be dated from it.
            first_capture: Some(Duration::from_millis(40)),
            silent: false,
        };
        let (tx, t, written) = spawn_loop(backend, mode);
        let t0 = Instant::now();
        while written.lock().unwrap().len() < writes && t0.elapsed() < Duration::from_secs(60) {
            std::thread::sleep(Duration::from_millis(5));
        }
        tx.send(Command::Shutdown).unwrap();
        t.join().unwrap();
        let w = written.lock().unwrap().clone();
        assert!(w.len() >= writes, "{} of {writes} writes: {w:?}", w.len());
        w
    }

    /// A source that sends nothing yet has not failed (the board within
    /// its 2 s frame wait) answers a setting change as a stalled one does,
    /// with the next frame's number, without a "no signal" card.
    #[test]
    fn a_silent_source_answers_setting_changes_without_a_card() {
        let backend = Scripted {
            sim: sim(ModeId::Raw),
            fails: Vec::new(),
            attempt: 0,
            first_capture: None,
            silent: true,
        };
        let (tx, t, written) = spawn_loop(backend, ModeId::Raw);
        let (reply, mark) = tokio::sync::oneshot::channel();
        tx.send(Command::SetDisplay(DisplayMap::default(), reply))
            .unwrap();
        let mark = mark.blocking_recv().expect("the call is answered");
        assert_eq!(
            mark,
            FrameMark {
                sequence: 1,
                timestamp_us: 0
            }
        );
        let (reply, snapshot) = tokio::sync::oneshot::channel();
        tx.send(Command::Snapshot(reply)).unwrap();
        assert!(snapshot.blocking_recv().expect("answered").is_none());
        tx.send(Command::Shutdown).unwrap();
        t.join().unwrap();
        assert!(written.lock().unwrap().is_empty(), "{written:?}");
    }

    /// Every stamp strictly after the one before, none later than the
    /// moment the sink wrote it, cards and frames both where expected.
    fn assert_one_clock(w: &[(bool, u64, u64)]) {
        for (i, pair) in w.windows(2).enumerate() {
            assert!(
                pair[1].1 > pair[0].1,
                "stamp {} not after {}: {w:?}",
                i + 1,
                i
            );
        }
        for (i, &(card, stamp, now)) in w.iter().enumerate() {
            assert!(
                stamp <= now,
                "write {i} (card {card}) stamped {} us in the future",
                stamp - now
            );
        }
        assert!(w[0].0, "the start-up card comes first: {w:?}");
        let after_pause = w.iter().skip(1).skip_while(|x| !x.0).skip_while(|x| x.0);
        assert!(after_pause.count() >= 2, "frames after the pause: {w:?}");
    }

    #[test]
    fn no_signal_and_frames_share_one_clock_never_in_the_future() {
        // A card at start-up, frames, a pause of two attempts (two cards),
        // frames again; in two-shot the pause falls inside a pair.
        let mut fails = vec![true, false, false, false, false, true, true];
        fails.resize(40, false);
        for mode in [ModeId::Raw, ModeId::TwoShot] {
            let w = published(mode, fails.clone(), 12);
            assert_one_clock(&w);
        }
    }

    #[test]
    fn lights_only_while_someone_needs_them() {
        // nobody watches, nothing records or waits: dark
        assert!(!lights_needed(Some(0), false, false));
        // a reader, a recording or a pending snapshot each turn them on
        assert!(lights_needed(Some(1), false, false));
        assert!(lights_needed(Some(0), true, false));
        assert!(lights_needed(Some(0), false, true));
        // the sink cannot tell (v4l2loopback 0.12.x, y4m): on
        assert!(lights_needed(None, false, false));
    }
}
