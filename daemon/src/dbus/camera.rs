//! `org.sdi.Camera1` on `/org/sdi/Camera0`: properties mirror the daemon's
//! state, methods validate their input and forward it to the frame loop.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::mpsc::Sender;
use std::sync::Mutex;
use std::time::Duration;

use sdi_core::mode::ModeId;
use tokio::sync::{oneshot, watch};
use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::{interface, Connection};

use super::client_fd::{self, recording_label};
use super::client_file;
use super::errors::{
    calibration_failed, check_range, configure_refused, dark_failed, frame_loop_stopped,
    invalid_mode, phase_failed, SdiError,
};
use super::fairness::Fairness;
use super::job_slot::{CancelCause, JobKind, JobSlot, JobTicket, MAX_JOB_SECONDS};
use super::paths::OutputKind;
use super::peers;
use crate::backend::{CaptureSettings, Limits};
use crate::calibration_store;
use crate::frame_loop::{Command, DarkStats, FrameMark, JobError, JobProgress, Reply};
use crate::recorder::{RecordingWriter, StopCause};
use crate::sink::SinkInfo;
use crate::stats::LoopStats;
use sdi_api::{CalibrationReply, DarkFrameReply, PhaseCalibrationReply, RecordingReply};
use sdi_config::RecordingSection;
use sdi_core::calibration::{CalibrationRecord, PhaseRecord};
use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
use sdi_recording::{Calibration, Header as RecHeader};

/// Largest number of frames one dark-frame or calibration call may average.
pub const MAX_AVERAGE_FRAMES: u32 = 10_000;
/// Largest fixed display range, DN.
pub use sdi_core::display::MAX_RANGE_DN;

/// Fixed facts about this camera, known at start.
#[derive(Debug, Clone)]
pub struct CameraInfo {
    pub backend: crate::backend::BackendName,
    pub device: String,
    /// The simulator's scene fixed by `[sim] scene`; None: each mode's own.
    pub scene: Option<sdi_core::scene::SceneId>,
    pub sink: SinkInfo,
    pub limits: Limits,
    pub sensor: sdi_core::sensor::SensorParams,
    /// Where calibrations are stored ([`crate::calibration_store`]); None = not stored.
    pub state_dir: Option<PathBuf>,
    /// Live backend state (the board: unplugged, simulator standing in).
    pub status: Option<crate::backend::status::StatusHandle>,
    /// Storage bounds of recordings.
    pub recording: RecordingSection,
    /// The rig `[lights]` drives; None when sdid drives no lights.
    pub lights: Option<String>,
}

/// Longest a StopRecording call waits for storage to take the rest of the
/// recording (the recorder thread goes on after that).
pub const RECORDING_FINISH_TIMEOUT: Duration = Duration::from_secs(5);

/// State changed by clients.
#[derive(Debug, Clone)]
struct State {
    mode: ModeId,
    capture: CaptureSettings,
    display: DisplayMap,
    recording: Option<PathBuf>,
    /// Why the daemon last stopped a recording by itself; reported once by
    /// the next StopRecording, and in Stats.
    recording_stopped: Option<String>,
}

pub struct Camera {
    info: CameraInfo,
    state: Mutex<State>,
    commands: Mutex<Sender<Command>>,
    stats: watch::Receiver<LoopStats>,
    calibration: watch::Receiver<Calibration>,
    /// Serializes mode and setting changes (zbus runs calls concurrently).
    change_lock: tokio::sync::Mutex<()>,
    /// The job holding the camera (dark frame, calibration), taken once per job.
    jobs: JobSlot,
    /// The frame loop's count of the running job's frames.
    job_progress: watch::Receiver<JobProgress>,
    /// Each caller's share of the method calls (one client's flood waits in its own queue).
    fairness: Fairness,
    /// Connections whose departure is watched for their frame streams.
    stream_owners: peers::Watched,
}

/// The reply of CaptureDarkFrame (core's statistics, the API's struct).
fn dark_frame_reply(s: &DarkStats) -> DarkFrameReply {
    DarkFrameReply {
        frames: s.frames,
        mean_dn: s.mean_dn,
        read_noise_variance_dn2: s.read_noise_variance_dn2,
        fixed_pattern_sigma_dn: s.fixed_pattern_sigma_dn,
    }
}

async fn caller_uid(conn: &Connection, hdr: &Header<'_>) -> Option<u32> {
    let sender = hdr.sender()?.to_owned();
    let proxy = zbus::fdo::DBusProxy::new(conn).await.ok()?;
    proxy
        .get_connection_unix_user(zbus::names::BusName::Unique(sender))
        .await
        .ok()
}

impl Camera {
    pub fn new(
        info: CameraInfo,
        mode: ModeId,
        capture: CaptureSettings,
        display: DisplayMap,
        commands: Sender<Command>,
        stats: watch::Receiver<LoopStats>,
        calibration: watch::Receiver<Calibration>,
    ) -> Self {
        Self {
            info,
            state: Mutex::new(State {
                mode,
                capture,
                display,
                recording: None,
                recording_stopped: None,
            }),
            commands: Mutex::new(commands),
            stats,
            calibration,
            change_lock: tokio::sync::Mutex::new(()),
            jobs: JobSlot::default(),
            job_progress: watch::channel(JobProgress::default()).1,
            fairness: Fairness::default(),
            stream_owners: peers::Watched::default(),
        }
    }

    /// Reads the running job's progress from the frame loop's `FrameLoop::job_progress`.
    pub fn with_job_progress(mut self, job_progress: watch::Receiver<JobProgress>) -> Self {
        self.job_progress = job_progress;
        self
    }

    fn state(&self) -> State {
        match self.state.lock() {
            Ok(s) => s.clone(),
            Err(p) => p.into_inner().clone(),
        }
    }

    fn update(&self, f: impl FnOnce(&mut State)) {
        match self.state.lock() {
            Ok(mut s) => f(&mut s),
            Err(p) => f(&mut p.into_inner()),
        }
    }

    /// `DeviceUnavailable` while the board is unplugged (nothing stands in).
    fn require_device(&self) -> Result<(), SdiError> {
        match self.info.status.as_ref().map(|h| h.get()) {
            Some(st) if !st.available => Err(SdiError::DeviceUnavailable(format!(
                "{}: {}",
                st.device, st.detail
            ))),
            _ => Ok(()),
        }
    }

    fn send(&self, cmd: Command) -> Result<(), SdiError> {
        let tx = self
            .commands
            .lock()
            .map_err(|_| SdiError::Failed("command channel poisoned".into()))?;
        tx.send(cmd).map_err(frame_loop_stopped)
    }

    async fn ask<T>(
        &self,
        make: impl FnOnce(oneshot::Sender<T>) -> Command,
    ) -> Result<T, SdiError> {
        let (tx, rx) = oneshot::channel();
        self.send(make(tx))?;
        rx.await.map_err(frame_loop_stopped)
    }

    /// Waits for the frame loop's answer to a setting change.
    async fn first_frame(rx: oneshot::Receiver<FrameMark>) -> Result<(u64, u64), SdiError> {
        let m = rx.await.map_err(frame_loop_stopped)?;
        Ok((m.sequence, m.timestamp_us))
    }

    async fn configure(
        &self,
        emitter: &SignalEmitter<'_>,
        f: impl FnOnce(&mut CaptureSettings),
    ) -> Result<(u64, u64), SdiError> {
        self.require_device()?;
        let guard = self.change_lock.lock().await;
        // A job puts its settings back when it ends: a change now would
        // be undone, so it is refused (the job took the change lock too).
        if let Some(busy) = self.jobs.busy("changing capture settings is refused") {
            return Err(busy);
        }
        let mut capture = self.state().capture;
        f(&mut capture);
        let l = self.info.limits;
        let period_us = 1e6 / capture.frame_rate_hz;
        if capture.exposure_us > period_us {
            return Err(SdiError::OutOfRange(format!(
                "ExposureUs = {} us exceeds the frame period {period_us:.1} us at {} Hz: allowed [{}, {period_us:.1}] us",
                capture.exposure_us, capture.frame_rate_hz, l.exposure_us.0
            )));
        }
        let (first_tx, first_rx) = oneshot::channel();
        let result = self
            .ask(|tx| Command::Configure(capture, tx, first_tx))
            .await?;
        let applied = result.map_err(configure_refused)?;
        self.update(|s| s.capture = applied);
        // Other changes may go ahead while this one waits for its frame.
        drop(guard);
        let _ = self.exposure_us_changed(emitter).await;
        let _ = self.frame_rate_changed(emitter).await;
        let _ = self.modulation_hz_changed(emitter).await;
        Self::first_frame(first_rx).await
    }

    async fn set_display(
        &self,
        emitter: &SignalEmitter<'_>,
        f: impl FnOnce(&mut DisplayMap),
    ) -> Result<(u64, u64), SdiError> {
        let guard = self.change_lock.lock().await;
        let mut d = self.state().display;
        f(&mut d);
        let (tx, rx) = oneshot::channel();
        self.send(Command::SetDisplay(d, tx))?;
        self.update(|s| s.display = d);
        drop(guard);
        let _ = self.colormap_changed(emitter).await;
        let _ = self.range_changed(emitter).await;
        Self::first_frame(rx).await
    }
}

/// A job in progress: the slot's ticket, the caller's departure, the deadline.
struct RunningJob<'a> {
    ticket: JobTicket<'a>,
    caller_left: std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>>,
    deadline: tokio::time::Instant,
    bound: Duration,
}

/// How often a running job's progress is published (`Job`).
const JOB_PROGRESS_PERIOD: Duration = Duration::from_millis(250);

/// Jobs: one at a time, taken once for all their steps, ended by their
/// caller's departure, `Cancel` or their deadline.
impl Camera {
    /// Checks `frames` against `[min, MAX_AVERAGE_FRAMES]`.
    fn check_frames(frames: u32, min: u32) -> Result<(), SdiError> {
        if frames < min || frames > MAX_AVERAGE_FRAMES {
            return Err(SdiError::OutOfRange(format!(
                "frames = {frames} is out of range: allowed [{min}, {MAX_AVERAGE_FRAMES}]"
            )));
        }
        Ok(())
    }

    /// Takes the camera for a job of `total` frames (`captures`: with the
    /// captures its settings need to settle): refused while another job or a
    /// recording runs, or when it would take longer than [`MAX_JOB_SECONDS`]
    /// at the current frame rate.
    async fn begin_job(
        &self,
        kind: JobKind,
        total: u32,
        captures: u32,
        hdr: &Header<'_>,
        conn: &Connection,
    ) -> Result<RunningJob<'_>, SdiError> {
        self.require_device()?;
        let rate_hz = self.state().capture.frame_rate_hz.max(1e-3);
        let estimate_s = f64::from(captures) / rate_hz;
        if estimate_s > MAX_JOB_SECONDS {
            return Err(SdiError::OutOfRange(format!(
                "the {} takes {captures} frames, {estimate_s:.0} s at {rate_hz} Hz: a job may take \
                 at most {MAX_JOB_SECONDS:.0} s (fewer frames, or a higher frame rate)",
                kind.name()
            )));
        }
        let caller = peers::caller(hdr);
        let owner = caller.as_ref().map_or_else(String::new, |c| c.to_string());
        let uid = caller_uid(conn, hdr).await;
        let now = *self.job_progress.borrow();
        let ticket = self.jobs.begin(kind, total, &owner, uid, now)?;
        {
            // After any setting change or recording start under way; those
            // that come later see the job.
            let _changes = self.change_lock.lock().await;
            if let Some(p) = self.state().recording {
                return Err(SdiError::Busy(format!(
                    "recording to {} runs: a {} would leave a gap in it; stop the recording first",
                    p.display(),
                    kind.name()
                )));
            }
        }
        let caller_left: std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>> =
            match caller {
                Some(c) => Box::pin(peers::left_bus(conn.clone(), c)),
                None => Box::pin(std::future::pending()),
            };
        // Twice the estimate and 10 s: room for a source slower than its rate.
        let bound = Duration::from_secs_f64(2.0 * estimate_s + 10.0);
        Ok(RunningJob {
            ticket,
            caller_left,
            deadline: tokio::time::Instant::now() + bound,
            bound,
        })
    }

    /// Runs one step of `job` in the frame loop, publishing its progress;
    /// cancels it (and answers `Cancelled`) when its caller leaves the bus,
    /// someone calls `Cancel` or the deadline passes.
    async fn job_step<T>(
        &self,
        job: &mut RunningJob<'_>,
        emitter: &SignalEmitter<'_>,
        make: impl FnOnce(Reply<Result<T, JobError>>) -> Command,
    ) -> Result<Result<T, JobError>, SdiError> {
        let kind = job.ticket.kind;
        let cancelled =
            |cause: CancelCause| SdiError::Cancelled(format!("the {} was {cause}", kind.name()));
        if let Some(cause) = job.ticket.cancel_requested() {
            return Err(cancelled(cause));
        }
        let (tx, mut rx) = oneshot::channel();
        self.send(make(tx))?;
        let mut tick = tokio::time::interval(JOB_PROGRESS_PERIOD);
        let cause = loop {
            tokio::select! {
                r = &mut rx => return r.map_err(frame_loop_stopped),
                c = job.ticket.cancelled() => break c,
                () = &mut job.caller_left => break CancelCause::CallerLeft,
                () = tokio::time::sleep_until(job.deadline) => break CancelCause::TimedOut(job.bound),
                _ = tick.tick() => {
                    job.ticket.progress.stage(*self.job_progress.borrow());
                    let _ = self.job_changed(emitter).await;
                }
            }
        };
        tracing::info!(job = kind.name(), "{cause}");
        self.send(Command::CancelJob)?;
        match rx.await.map_err(frame_loop_stopped)? {
            Err(JobError::Cancelled) => Err(cancelled(cause)),
            // It finished before the cancel reached it.
            done => Ok(done),
        }
    }

    /// Ends a step: the next step's frames count on from its `frames`.
    fn job_step_done(&self, job: &RunningJob<'_>, frames: u32) {
        job.ticket
            .progress
            .next_stage(frames, *self.job_progress.borrow());
    }

    /// A dark-frame capture of `frames` as a job of its own.
    async fn dark_frame_job(
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
    async fn calibration_job(
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
    async fn phase_job(
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
}

impl Camera {
    /// The file being recorded to, if any.
    pub fn recording_path(&self) -> Option<PathBuf> {
        self.state().recording
    }

    /// The Stats property as of now (the frame rate decays to 0 when frames stop).
    pub fn current_stats(&self) -> sdi_api::Stats {
        let s = self.stats.borrow().clone();
        let now = std::time::Instant::now();
        let (mut device_available, mut device_state, health) =
            match self.info.status.as_ref().map(|h| h.get()) {
                Some(st) => (st.available, st.detail, st.health),
                None => (true, String::new(), None),
            };
        if let Some(why) = s.stalled {
            device_available = false;
            if device_state.is_empty() {
                device_state = format!("no frames: {why}");
            }
        }
        let st = self.state();
        sdi_api::Stats {
            fps: s.fps_at(now, st.capture.frame_rate_hz),
            last_frame_age_s: s.last_frame_at.map_or(-1.0, |t| (now - t).as_secs_f64()),
            device_available,
            device_state,
            recording_stopped: st.recording_stopped.unwrap_or_default(),
            board_temperature_c: health.map_or(f64::NAN, |h| f64::from(h.sensor_c)),
            illumination_temperature_c: health.map_or(f64::NAN, |h| f64::from(h.illumination_c)),
            output_overflows: health.map_or(0, |h| h.output_overflows),
            ..s.counters
        }
    }
}

/// Recording and snapshot steps shared by the path and descriptor methods.
impl Camera {
    fn recording_header(&self, st: &State) -> RecHeader {
        let mut sensor = self.info.sensor.clone();
        sensor.exposure_us = st.capture.exposure_us;
        sensor.frame_rate_hz = st.capture.frame_rate_hz;
        sensor.modulation_hz = st.capture.modulation_hz;
        RecHeader {
            format_version: 1,
            mode: st.mode.name().into(),
            backend: self.info.backend.to_string(),
            sensor,
            exposure_us: st.capture.exposure_us,
            frame_rate_hz: st.capture.frame_rate_hz,
            modulation_hz: st.capture.modulation_hz,
            started_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
            calibration: self.calibration.borrow().clone(),
        }
    }

    /// Opens a writer with `open` (off the async runtime) and hands it to the
    /// frame loop; `label` is what the Recording property shows.
    async fn begin_recording(
        &self,
        label: PathBuf,
        emitter: &SignalEmitter<'_>,
        open: impl FnOnce(&RecHeader, RecordingSection) -> std::io::Result<RecordingWriter>
            + Send
            + 'static,
    ) -> Result<(), SdiError> {
        let _guard = self.change_lock.lock().await;
        if let Some(busy) = self
            .jobs
            .busy("a recording is refused (it would have a gap while the job takes the frames)")
        {
            return Err(busy);
        }
        let st = self.state();
        if let Some(p) = &st.recording {
            return Err(SdiError::Busy(format!(
                "already recording to {}",
                p.display()
            )));
        }
        let header = self.recording_header(&st);
        let limits = self.info.recording;
        let mut writer = tokio::task::spawn_blocking(move || open(&header, limits))
            .await
            .map_err(|e| SdiError::Failed(e.to_string()))?
            .map_err(|e| SdiError::InvalidPath(format!("{}: {e}", label.display())))?;
        let ended = writer.take_ended();
        self.ask(|tx| Command::StartRecording(Box::new(writer), tx))
            .await?;
        tracing::info!(path = ?label, "recording started");
        self.update(|s| {
            s.recording = Some(label.clone());
            s.recording_stopped = None;
        });
        let _ = self.recording_changed(emitter).await;
        if let Some(ended) = ended {
            let server = emitter.connection().object_server().clone();
            let path = emitter.path().to_owned();
            tokio::spawn(async move {
                let Ok(cause) = ended.await else { return };
                if let Ok(iface) = server.interface::<_, Camera>(path).await {
                    iface
                        .get()
                        .await
                        .recording_ended(label, cause, iface.signal_emitter())
                        .await;
                }
            });
        }
        Ok(())
    }

    /// Creates `path` for a path method: a new file directly in the state
    /// directory, owned by the caller (`client_file`).
    fn create_in_state_dir(
        &self,
        path: &str,
        allowed: &[OutputKind],
        uid: Option<u32>,
    ) -> Result<client_file::StateDirFile, SdiError> {
        client_file::create(self.info.state_dir.as_deref(), path, allowed, uid)
    }

    /// The recorder stopped by itself: take it from the frame loop, clear
    /// the Recording property, emit `RecordingStopped` and Stats at once.
    async fn recording_ended(&self, label: PathBuf, cause: StopCause, emitter: &SignalEmitter<'_>) {
        let _guard = self.change_lock.lock().await;
        if self.state().recording.as_ref() != Some(&label) {
            return; // stopped by a client meanwhile
        }
        let frames = match self.ask(Command::StopRecording).await {
            Ok(Some(w)) => {
                tokio::task::spawn_blocking(move || w.finish_within(RECORDING_FINISH_TIMEOUT))
                    .await
                    .ok()
                    .and_then(Result::ok)
                    .map_or(0, |s| s.frames)
            }
            _ => 0,
        };
        let reason = format!(
            "recording {} stopped after {frames} frames: {cause}",
            label.display()
        );
        tracing::error!(path = ?label, frames, "{reason}");
        self.update(|s| {
            s.recording = None;
            s.recording_stopped = Some(reason.clone());
        });
        let _ = self.recording_changed(emitter).await;
        let _ = self.stats_changed(emitter).await;
        let _ =
            Self::recording_stopped(emitter, &label.display().to_string(), &reason, frames).await;
    }

    /// The latest processed frame, waiting up to 2 s for the first one.
    async fn latest_frame(&self) -> Result<crate::frame_loop::SnapshotData, SdiError> {
        self.require_device()?;
        // The job takes the frames until it ends: answer now, not then.
        if let Some(busy) = self
            .jobs
            .busy("a snapshot is refused (the frames go to the job)")
        {
            return Err(busy);
        }
        for _ in 0..20 {
            if let Some(snap) = self.ask(Command::Snapshot).await? {
                return Ok(snap);
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        Err(SdiError::NoFrame("no frame has been processed yet".into()))
    }
}

#[interface(name = "org.sdi.Camera1")]
impl Camera {
    /// Switches the mode; the output stays open. Returns once the first
    /// frame of the new mode has been published, with its sequence number and
    /// capture timestamp (us): every frame from it on is of the new mode,
    /// every frame before of the old (docs/dbus.md, "Setting changes").
    #[zbus(out_args("sequence", "timestamp_us"))]
    async fn set_mode(
        &self,
        mode: &str,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let m = ModeId::from_name(mode).map_err(|_| invalid_mode(mode))?;
        let guard = self.change_lock.lock().await;
        let (tx, rx) = oneshot::channel();
        self.send(Command::SetMode(m, tx))?;
        let changed = self.state().mode != m;
        self.update(|s| s.mode = m);
        // Other changes may go ahead while this one waits for its frame.
        drop(guard);
        if changed {
            tracing::info!(mode = m.name(), "mode changed");
            let _ = self.mode_changed(&emitter).await;
            let _ = self.setup_changed(&emitter).await;
        }
        Self::first_frame(rx).await
    }

    /// Exposure per frame, microseconds; at most the frame period.
    #[zbus(out_args("sequence", "timestamp_us"))]
    async fn set_exposure_us(
        &self,
        exposure_us: f64,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let (lo, hi) = self.info.limits.exposure_us;
        let v = check_range("ExposureUs", exposure_us, lo, hi, "us")?;
        self.configure(&emitter, |c| c.exposure_us = v).await
    }

    /// Frame rate, Hz.
    #[zbus(out_args("sequence", "timestamp_us"))]
    async fn set_frame_rate(
        &self,
        frame_rate_hz: f64,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let (lo, hi) = self.info.limits.frame_rate_hz;
        let v = check_range("FrameRate", frame_rate_hz, lo, hi, "Hz")?;
        self.configure(&emitter, |c| c.frame_rate_hz = v).await
    }

    /// Modulation (carrier) frequency, Hz.
    #[zbus(out_args("sequence", "timestamp_us"))]
    async fn set_modulation_hz(
        &self,
        modulation_hz: f64,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let (lo, hi) = self.info.limits.modulation_hz;
        let v = check_range("ModulationHz", modulation_hz, lo, hi, "Hz")?;
        self.configure(&emitter, |c| c.modulation_hz = v).await
    }

    /// Colour map of the view stream and PNG snapshots: "diverging" or "grey".
    #[zbus(out_args("sequence", "timestamp_us"))]
    async fn set_colormap(
        &self,
        colormap: &str,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let c: Colormap = colormap.parse().map_err(|_| {
            SdiError::OutOfRange(format!(
                "unknown colormap '{}': allowed {}",
                colormap.escape_debug(),
                Colormap::NAMES.join(", ")
            ))
        })?;
        self.set_display(&emitter, |d| d.colormap = c).await
    }

    /// Display range: |DN| mapped to full scale; 0 = symmetric auto range per frame.
    #[zbus(out_args("sequence", "timestamp_us"))]
    async fn set_range(
        &self,
        max_abs_dn: f64,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let v = check_range("Range", max_abs_dn, 0.0, MAX_RANGE_DN, "DN")?;
        self.set_display(&emitter, |d| {
            d.range = if v == 0.0 {
                DisplayRange::SymmetricAuto
            } else {
                DisplayRange::Fixed {
                    max_abs_dn: v as f32,
                }
            }
        })
        .await
    }

    /// Averages `frames` frames with both sources off into the dark frame the
    /// pipelines subtract; returns its statistics.
    async fn capture_dark_frame(
        &self,
        frames: u32,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
    ) -> Result<DarkFrameReply, SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let r = self.dark_frame_job(frames, &hdr, conn, &emitter).await;
        let _ = self.job_changed(&emitter).await;
        Ok(dark_frame_reply(&r?))
    }

    /// Calibration: the dark frame, read-noise variance (DN^2, eq. skellamvar
    /// with no light) and fixed-pattern sigma from `frames` >= 2 dark frames;
    /// then photon transfer (LS1 alone at 5 exposures, `frames` frames each):
    /// gain g = rho eta (DN/electron) and read variance with standard errors,
    /// which the separation mode's H uses from then on.
    async fn calibrate(
        &self,
        frames: u32,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
    ) -> Result<CalibrationReply, SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let r = self.calibration_job(frames, &hdr, conn, &emitter).await;
        let _ = self.job_changed(&emitter).await;
        let (s, fit) = r?;
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
        Ok(reply)
    }

    /// Phase calibration of the board: `frames` frames with LS1 alone lit
    /// (through `[lights]`, else LS2 covered by hand), their quads' (I, Q)
    /// summed and the axis of LS1 - LS2 fitted; the board decodes with it
    /// from then on, and it is stored with the other calibration
    /// (docs/hardware.md, "Phase").
    async fn calibrate_phase(
        &self,
        frames: u32,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
    ) -> Result<PhaseCalibrationReply, SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        Self::check_frames(frames, 1)?;
        if self.info.backend != crate::backend::BackendName::Opt8241 {
            return Err(SdiError::Failed(format!(
                "phase calibration needs the OPT8241-CDK's raw quads; the backend is {} \
                 (set backend = \"opt8241\")",
                self.info.backend
            )));
        }
        let r = self.phase_job(frames, &hdr, conn, &emitter).await;
        let _ = self.job_changed(&emitter).await;
        let fit = r?;
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
        Ok(reply)
    }

    /// Starts recording raw sensor frames to a new `.sdirec` file named
    /// `STATE_DIR/NAME.sdirec`: the only path the daemon creates itself
    /// (docs/dbus.md, "Path methods"); anything else is `InvalidPath`.
    async fn start_recording(
        &self,
        path: &str,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
    ) -> Result<(), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let uid = caller_uid(conn, &hdr).await;
        let out = self.create_in_state_dir(path, &[OutputKind::Recording], uid)?;
        let (file, label) = match out.file.try_clone() {
            Ok(f) => (f, out.path.clone()),
            Err(e) => {
                out.discard();
                return Err(SdiError::Failed(format!("duplicating a descriptor: {e}")));
            }
        };
        let l2 = label.clone();
        let started = self
            .begin_recording(label, &emitter, move |header, limits| {
                RecordingWriter::from_file(file, &l2, header, limits)
            })
            .await;
        if started.is_err() {
            out.discard();
        }
        started
    }

    /// Starts recording into `fd`, a new empty file the caller opened for
    /// writing (the daemon never sees a path); `label` (e.g. the path of
    /// the file) is what the Recording property shows.
    async fn start_recording_to_fd(
        &self,
        fd: zbus::zvariant::OwnedFd,
        label: &str,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let label = PathBuf::from(recording_label(label)?);
        let file = client_fd::output_file(fd.into())?;
        let l2 = label.clone();
        self.begin_recording(label, &emitter, move |header, limits| {
            RecordingWriter::from_file(file, &l2, header, limits)
        })
        .await
    }

    /// Stops recording; returns {path, frames, dropped}.
    async fn stop_recording(
        &self,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<RecordingReply, SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let _guard = self.change_lock.lock().await;
        let Some(path) = self.state().recording else {
            let mut stopped = None;
            self.update(|s| stopped = s.recording_stopped.take());
            return Err(match stopped {
                Some(why) => SdiError::RecordingStopped(why),
                None => SdiError::NotRecording("no recording in progress".into()),
            });
        };
        let writer = self.ask(Command::StopRecording).await?;
        self.update(|s| s.recording = None);
        let _ = self.recording_changed(&emitter).await;
        let writer =
            writer.ok_or_else(|| SdiError::NotRecording("no recording in progress".into()))?;
        // The recorder thread writes the rest; the frame loop goes on meanwhile.
        let summary =
            tokio::task::spawn_blocking(move || writer.finish_within(RECORDING_FINISH_TIMEOUT))
                .await
                .map_err(|e| SdiError::Failed(e.to_string()))?
                .map_err(|e| SdiError::Failed(format!("{}: {e}", path.display())))?;
        tracing::info!(path = ?path, frames = summary.frames, dropped = summary.dropped, "recording stopped");
        Ok(RecordingReply {
            path: path.display().to_string(),
            frames: summary.frames,
            dropped: summary.dropped,
        })
    }

    /// Writes the latest processed frame to a new file `STATE_DIR/NAME.png`
    /// (as displayed) or `NAME.npy` (signed DN, float32, shape (height,
    /// width)): the only paths the daemon creates itself; anything else is
    /// `InvalidPath`.
    async fn snapshot(
        &self,
        path: &str,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> Result<(), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let uid = caller_uid(conn, &hdr).await;
        let out = self.create_in_state_dir(path, &[OutputKind::Png, OutputKind::Npy], uid)?;
        let written = match (out.file.try_clone(), self.latest_frame().await) {
            (Ok(file), Ok(snap)) => {
                let kind = out.kind;
                tokio::task::spawn_blocking(move || crate::snapshot::write_to(file, kind, &snap))
                    .await
                    .map_err(|e| SdiError::Failed(e.to_string()))
                    .and_then(|r| {
                        r.map_err(|e| SdiError::Failed(format!("{}: {e}", out.path.display())))
                    })
            }
            (Err(e), _) => Err(SdiError::Failed(format!("duplicating a descriptor: {e}"))),
            (_, Err(e)) => Err(e),
        };
        if written.is_err() {
            out.discard();
        }
        written
    }

    /// Writes the latest processed frame into `fd`, a new empty file the
    /// caller opened for writing; `format` is "png" or "npy".
    async fn snapshot_to_fd(
        &self,
        fd: zbus::zvariant::OwnedFd,
        format: &str,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<(), SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let kind = client_fd::snapshot_format(format)?;
        let file = client_fd::output_file(fd.into())?;
        let snap = self.latest_frame().await?;
        tokio::task::spawn_blocking(move || crate::snapshot::write_to(file, kind, &snap))
            .await
            .map_err(|e| SdiError::Failed(e.to_string()))?
            .map_err(|e| SdiError::Failed(format!("writing the snapshot: {e}")))
    }

    /// Writes every mode output into `fd`, the writing end of a pipe or
    /// socket the caller holds the other end of (`sdi_api::frame_stream`'s
    /// format), until the caller closes it. Frames a slow reader cannot
    /// take are dropped and counted in the headers.
    async fn stream_frames(
        &self,
        fd: zbus::zvariant::OwnedFd,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> Result<(), SdiError> {
        use crate::frame_stream::StreamError;
        let _turn = self.fairness.turn(&hdr).await;
        let target = client_fd::stream_target(fd.into())?;
        let caller = peers::caller(&hdr)
            .ok_or_else(|| SdiError::Failed("the call names no sender".into()))?;
        let owner = caller.to_string();
        self.ask(|reply| Command::StreamFrames(target, owner.clone(), reply))
            .await?
            .map_err(|e| match e {
                StreamError::TooMany | StreamError::TooManyForPeer => SdiError::Busy(e.to_string()),
                StreamError::Thread(_) => SdiError::Failed(e.to_string()),
            })?;
        // The stream is the caller's: it ends when the caller leaves the
        // bus. One watch per connection, however many streams it opens.
        let commands = self.commands.lock().map(|tx| tx.clone());
        if let (Ok(commands), true) = (commands, self.stream_owners.insert(&owner)) {
            let conn = conn.clone();
            let owners = self.stream_owners.clone();
            tokio::spawn(async move {
                peers::left_bus(conn, caller).await;
                owners.remove(&owner);
                let _ = commands.send(Command::PeerLeft(owner));
            });
        }
        Ok(())
    }

    /// Cancels the running job (dark frame, calibration, phase calibration):
    /// its call ends with `org.sdi.Error.Cancelled` and its settings are put
    /// back. Its caller, a connection of the same user, or root may; returns
    /// the job's name, "" when none runs.
    async fn cancel(
        &self,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> Result<String, SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        let caller = peers::caller(&hdr).map_or_else(String::new, |c| c.to_string());
        let uid = caller_uid(conn, &hdr).await;
        let kind = self.jobs.cancel(&caller, uid)?;
        if let Some(k) = kind {
            tracing::info!(job = k.name(), by = caller, "cancel asked");
        }
        Ok(kind.map_or_else(String::new, |k| k.name().to_owned()))
    }

    /// The job holding the camera: {name ("" when none), frames_done,
    /// frames_total}; emitted when one starts and ends and about four times
    /// a second while it runs.
    #[zbus(property)]
    async fn job(&self) -> sdi_api::JobProgress {
        match self.jobs.progress() {
            Some((kind, frames_done, frames_total)) => sdi_api::JobProgress {
                name: kind.name().to_owned(),
                frames_done,
                frames_total,
            },
            None => sdi_api::JobProgress::default(),
        }
    }

    /// Current mode name.
    #[zbus(property)]
    async fn mode(&self) -> String {
        self.state().mode.name().into()
    }

    /// All mode names.
    #[zbus(property(emits_changed_signal = "const"))]
    async fn modes(&self) -> Vec<String> {
        ModeId::names().into_iter().map(String::from).collect()
    }

    /// The ranges the setters accept, by property name: "ExposureUs",
    /// "FrameRate", "ModulationHz" -> (min, max); the board's own while it
    /// is the source.
    #[zbus(property(emits_changed_signal = "const"))]
    async fn limits(&self) -> HashMap<String, (f64, f64)> {
        let l = self.info.limits;
        HashMap::from([
            ("ExposureUs".to_owned(), l.exposure_us),
            ("FrameRate".to_owned(), l.frame_rate_hz),
            ("ModulationHz".to_owned(), l.modulation_hz),
        ])
    }

    /// Physical setup the current mode expects: {ls1, ls2, optics}.
    #[zbus(property)]
    async fn setup(&self) -> HashMap<String, String> {
        let s = self.state().mode.setup();
        HashMap::from([
            ("ls1".to_owned(), s.ls1.to_owned()),
            ("ls2".to_owned(), s.ls2.to_owned()),
            ("optics".to_owned(), s.optics.to_owned()),
        ])
    }

    /// Backend delivering frames now (with the board: "sim" while the
    /// simulator stands in for an unplugged board).
    #[zbus(property(emits_changed_signal = "false"))]
    async fn backend(&self) -> String {
        match &self.info.status {
            Some(h) => h.get().backend,
            None => self.info.backend.to_string(),
        }
    }

    /// The simulator's scene (the one `[sim] scene` fixes, else the mode's
    /// own); "" when the frames come from a sensor or a recording. Follows
    /// Backend, so no change signal.
    #[zbus(property(emits_changed_signal = "false"))]
    async fn scene(&self) -> String {
        if self.backend().await != "sim" {
            return String::new();
        }
        let scene = self
            .info
            .scene
            .unwrap_or_else(|| self.state().mode.spec().default_scene);
        scene.name().into()
    }

    /// Sensor device and output device, "sensor -> output".
    #[zbus(property(emits_changed_signal = "false"))]
    async fn device(&self) -> String {
        let sensor = match &self.info.status {
            Some(h) => h.get().device,
            None => self.info.device.clone(),
        };
        format!("{sensor} -> {}", self.info.sink.device)
    }

    /// The sink publishing the output: "loopback", "pipewire" or "y4m".
    #[zbus(property(emits_changed_signal = "const"))]
    async fn sink(&self) -> String {
        self.info.sink.kind.to_string()
    }

    /// Output pixel format.
    #[zbus(property(emits_changed_signal = "const"))]
    async fn format(&self) -> String {
        self.info.sink.format.clone()
    }

    #[zbus(property(emits_changed_signal = "const"))]
    async fn width(&self) -> u32 {
        self.info.sink.width
    }

    #[zbus(property(emits_changed_signal = "const"))]
    async fn height(&self) -> u32 {
        self.info.sink.height
    }

    /// Frames per second, Hz.
    #[zbus(property)]
    async fn frame_rate(&self) -> f64 {
        self.state().capture.frame_rate_hz
    }

    #[zbus(property)]
    async fn exposure_us(&self) -> f64 {
        self.state().capture.exposure_us
    }

    #[zbus(property)]
    async fn modulation_hz(&self) -> f64 {
        self.state().capture.modulation_hz
    }

    #[zbus(property)]
    async fn colormap(&self) -> String {
        self.state().display.colormap.name().into()
    }

    /// |DN| at full scale; 0 = symmetric auto range.
    #[zbus(property)]
    async fn range(&self) -> f64 {
        match self.state().display.range {
            DisplayRange::SymmetricAuto => 0.0,
            DisplayRange::Fixed { max_abs_dn } => max_abs_dn as f64,
        }
    }

    /// Path being recorded to, "" when not recording.
    #[zbus(property)]
    async fn recording(&self) -> String {
        self.state()
            .recording
            .map(|p| p.display().to_string())
            .unwrap_or_default()
    }

    /// {frames, fps, last_frame_age_s, latency_us, latency_max_us, dropped_view,
    /// dropped_recording, device_available, device_state, recording_stopped,
    /// board_temperature_c, illumination_temperature_c, output_overflows};
    /// emitted about once a second while it changes.
    #[zbus(property)]
    async fn stats(&self) -> sdi_api::Stats {
        self.current_stats()
    }

    /// The daemon stopped a recording by itself (size limit, free-space
    /// floor, disk full); `reason` says which. Every frame written stays readable.
    #[zbus(signal)]
    async fn recording_stopped(
        emitter: &SignalEmitter<'_>,
        path: &str,
        reason: &str,
        frames: u64,
    ) -> zbus::Result<()>;
}
