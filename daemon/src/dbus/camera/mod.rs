//! `org.sdi.Camera1` on `/org/sdi/Camera0`: properties mirror the daemon's
//! state, methods validate their input and forward it to the frame loop.
//!
//! The interface is the one `#[interface]` block below, its methods thin;
//! the work is in `impl Camera` blocks by feature: `settings`, `jobs` and
//! `calibration`, `recording`, `snapshot`, `streams`; `state` is what
//! clients changed, `commands` the channel to the frame loop.

mod calibration;
mod caller;
mod commands;
mod info;
mod jobs;
mod recording;
mod settings;
mod snapshot;
mod state;
mod streams;

use std::collections::HashMap;
use std::sync::mpsc::Sender;
use std::sync::Mutex;

use sdi_core::mode::ModeId;
use tokio::sync::watch;
use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::{interface, Connection};

use super::errors::{check_range, SdiError};
use super::fairness::Fairness;
use super::job_slot::JobSlot;
use super::peers;
use crate::backend::CaptureSettings;
use crate::frame_loop::{Command, JobProgress};
use crate::stats::LoopStats;
use sdi_api::{CalibrationReply, DarkFrameReply, PhaseCalibrationReply, RecordingReply};
use sdi_core::display::{DisplayMap, DisplayRange};
use sdi_recording::Calibration;
use state::State;

pub use info::CameraInfo;
pub use jobs::MAX_AVERAGE_FRAMES;
pub use recording::RECORDING_FINISH_TIMEOUT;
/// Largest fixed display range, DN.
pub use sdi_core::display::MAX_RANGE_DN;

/// The object serving `org.sdi.Camera1`.
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
        self.switch_mode(mode, &emitter).await
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
        let c = settings::parse_colormap(colormap)?;
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
        self.set_display(&emitter, |d| d.range = settings::display_range(v))
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
        Ok(calibration::dark_frame_reply(&r?))
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
        Ok(self.calibration_reply(s, fit).await)
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
        self.require_raw_quads()?;
        let r = self.phase_job(frames, &hdr, conn, &emitter).await;
        let _ = self.job_changed(&emitter).await;
        Ok(self.phase_reply(r?).await)
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
        self.record_to_state_dir(path, &hdr, conn, &emitter).await
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
        self.record_to_fd(fd, label, &emitter).await
    }

    /// Stops recording; returns {path, frames, dropped}.
    async fn stop_recording(
        &self,
        #[zbus(signal_emitter)] emitter: SignalEmitter<'_>,
        #[zbus(header)] hdr: Header<'_>,
    ) -> Result<RecordingReply, SdiError> {
        let _turn = self.fairness.turn(&hdr).await;
        self.end_recording(&emitter).await
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
        self.snapshot_to_state_dir(path, &hdr, conn).await
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
        self.snapshot_into_fd(fd, format).await
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
        let _turn = self.fairness.turn(&hdr).await;
        self.open_stream(fd, &hdr, conn).await
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
        self.cancel_job(&hdr, conn).await
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

    /// The camera's name among several: the board's USB serial, `sim-N`
    /// for the simulator (`sdictl --camera SERIAL`).
    #[zbus(property(emits_changed_signal = "const"))]
    async fn serial(&self) -> String {
        self.info.serial.clone()
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
