//! The frame loop: a dedicated thread that captures, processes and hands
//! frames on. It never waits on D-Bus, logging or disk: commands arrive on a
//! channel polled between frames, replies go out on one-shot channels, and
//! outputs (through the [`Fanout`]) and recordings sit behind bounded
//! non-blocking queues.
//!
//! Here the loop itself (capture, stamp, process, publish); by concern:
//! `commands` (what callers ask), `marks` (setting changes answered with
//! their first frame), `jobs` (dark frame and calibrations), `lights`,
//! `snapshot`.

mod commands;
mod jobs;
mod lights;
mod marks;
mod snapshot;
#[cfg(test)]
mod tests;

use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::time::{Duration, Instant};

use sdi_core::mode::ModeId;
use sdi_core::separation::{LiveMethod, LiveSeparatorConfig};
use sdi_core::{Frame, Image};
use tokio::sync::watch;

use crate::backend::pacer::Pacer;
use crate::backend::{Backend, BackendError};
use crate::cause_log::{repeats, CauseLog};
use crate::fanout::Fanout;
use crate::job::Settling;
use crate::monotonic::{monotonic_now_us, MonotonicClock};
use crate::out_frame::OutFrame;
use crate::publish_clock::PublishClock;
use crate::recorder::RecordingWriter;
use crate::sink::output::Output;
use crate::stats::{LoopStats, StatsWindow};
use jobs::ActiveJob;
use marks::PendingMark;
use sdi_core::display::DisplayMap;
use sdi_core::mode::{build_pipeline, ModeOutput, Pipeline, PipelineConfig};
use sdi_recording::Calibration;

pub use commands::{Command, Reply};
pub use jobs::{DarkStats, JobError, JobProgress};
pub use lights::lights_needed;
pub use marks::FrameMark;
pub use snapshot::SnapshotData;

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

pub struct FrameLoop {
    backend: Box<dyn Backend>,
    pipeline: Box<dyn Pipeline>,
    mode: ModeId,
    display: DisplayMap,
    /// The sinks, clients' frame streams (`StreamFrames`) and the latest
    /// frame.
    fanout: Fanout,
    recorder: Option<RecordingWriter>,
    dark: Option<(u32, Image<f32>)>,
    calibration: Calibration,
    /// Dark capture or calibration running instead of the pipeline.
    job: Option<ActiveJob>,
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
            fanout: Fanout::new(output),
            recorder: None,
            dark: None,
            calibration: Calibration::default(),
            job: None,
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
        self.fanout.no_signal(card_us);
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
        } else if self.pipeline.process(frame).is_some() {
            // The output is handed over, not copied: the pipeline writes the
            // next one into an earlier output nobody holds any more.
            let spare = self
                .fanout
                .take_spare()
                .unwrap_or_else(|| ModeOutput::new(0, 0));
            let out = OutFrame::new(self.pipeline.take_output(spare), self.mode, self.display);
            let published = self.fanout.publish(out).output.sequence;
            self.answer_marks(published);
            if self.lights.is_settled() {
                self.answer_pending_snapshots();
            }
        }
    }

    /// Sends Stats with the drop counters of the output and the recorder.
    fn publish_stats(&mut self) {
        let mut s = self.stats.current.clone();
        s.counters.dropped_view = self.fanout.dropped_view();
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
}
