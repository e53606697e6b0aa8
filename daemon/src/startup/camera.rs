//! One camera brought up: its backend and sinks opened from its plan
//! ([`crate::camera_plan`]), its stored calibrations applied, its frame loop
//! started and its `org.sdi.Camera1` object served at the next path.

use std::sync::mpsc;
use std::sync::Arc;
use std::thread::JoinHandle;

use sdi_config::Config;
use sdi_core::display::{DisplayMap, DisplayRange};
use sdi_core::mode::ModeId;
use sdi_core::quad_phase::PhaseAxis;
use sdi_core::sensor::SkellamMixing;
use sdi_recording::{Calibration, RecordingReader};
use tokio::sync::{watch, Notify};

use super::{emit_stats, StartError, StartOptions};
use crate::backend::select as backend_select;
use crate::backend::{Backend, BackendName, CaptureSettings};
use crate::calibration_store;
use crate::camera_plan::{self, CameraPlan};
use crate::dbus::camera::{Camera, CameraInfo};
use crate::dbus::{camera_path, BUS_NAME};
use crate::frame_loop::{Command, FrameLoop};
use crate::recorder::RecordingWriter;
use crate::sink::output::Output;
use crate::sink::select as sink_select;
use crate::sink::{SinkInfo, SinkKindName};
use crate::stats::LoopStats;

/// The cameras served, in the order of their objects.
#[derive(Default)]
pub(super) struct Served {
    pub cameras: Vec<Running>,
}

impl Served {
    /// The serials served.
    pub fn serials(&self) -> Vec<String> {
        self.cameras.iter().map(|c| c.serial.clone()).collect()
    }
}

/// A served camera: its object path, serial, frame loop and the task
/// that signals its Stats.
pub(super) struct Running {
    pub path: String,
    pub serial: String,
    pub frames: FrameLoopHandle,
    pub stats: tokio::task::JoinHandle<()>,
}

/// Opens the camera of `plan` (off the runtime: a board's USB I/O can
/// take seconds), starts its frame loop and serves it at the next path;
/// `exits` is told when its board is unplugged with `on_unplug = "exit"`.
/// Returns its first screen.
pub(super) async fn serve_camera(
    conn: &zbus::Connection,
    options: &StartOptions,
    plan: CameraPlan,
    served: &mut Served,
    exits: &Arc<Notify>,
) -> Result<String, StartError> {
    let opening = options.clone();
    let opened = tokio::task::spawn_blocking(move || open_camera(&opening, plan))
        .await
        .map_err(StartError::OpenTask)??;
    if let Some(exit) = opened.exit.clone() {
        let exits = exits.clone();
        tokio::spawn(async move {
            exit.notified().await;
            exits.notify_one();
        });
    }
    let screen = opened.first_screen.clone();
    let serial = opened.info.serial.clone();
    let config = opened.config.clone();
    let (camera, frames) = start_frame_loop(opened, &config)?;
    let path = camera_path(served.cameras.len());
    conn.object_server()
        .at(path.as_str(), camera)
        .await
        .map_err(StartError::Serve)?;
    tracing::info!(name = BUS_NAME, path, serial, "serving D-Bus API");
    let stats = tokio::spawn(emit_stats(conn.clone(), path.clone()));
    served.cameras.push(Running {
        path,
        serial,
        frames,
        stats,
    });
    Ok(screen)
}

/// sdid's first screen, after the private bus's lines: what is published,
/// from where, why this sink, and what to open.
fn first_screen(
    source: &str,
    mode: ModeId,
    sink: &SinkInfo,
    also: &[SinkInfo],
    reasons: Option<&str>,
    camera: Option<&str>,
) -> String {
    let published = match sink.kind {
        SinkKindName::Y4m => "a y4m stream",
        SinkKindName::Pipewire => "a PipeWire camera",
        SinkKindName::Loopback => "a V4L2 camera (v4l2loopback)",
    };
    let mut lines = vec![format!(
        "sdid: {source}, mode {}, published as {published}",
        mode.name()
    )];
    if let Some(reasons) = reasons {
        lines.push(format!("  why:     {reasons}"));
    }
    lines.push(format!(
        "  view:    {}",
        sink_select::how_to_watch(sink.kind, &sink.device)
    ));
    for a in also {
        lines.push(format!(
            "  also:    {}",
            sink_select::how_to_watch(a.kind, &a.device)
        ));
    }
    let named = camera.map(|s| format!("--camera {s} ")).unwrap_or_default();
    lines.push(format!(
        "  control: sdictl {named}set-mode depth-edge   (sdictl modes: every mode; sdictl status)"
    ));
    lines.join("\n")
}

/// The display mapping of a validated `[display]` section.
fn display_from(c: &Config) -> DisplayMap {
    let r = c.display.range_max_abs_dn;
    let range = if r == 0.0 {
        DisplayRange::SymmetricAuto
    } else {
        DisplayRange::Fixed {
            max_abs_dn: r as f32,
        }
    };
    DisplayMap {
        colormap: c.display.colormap,
        range,
    }
}

/// The mode a replay starts in without `--mode`: the recording's.
fn recorded_mode(c: &Config) -> Option<ModeId> {
    let path = c.replay.path.as_deref()?;
    let reader = RecordingReader::open(path).ok()?;
    ModeId::from_name(&reader.header().mode).ok()
}

/// The backend and the output, opened, with what the bus serves about them.
struct Opened {
    /// The camera's own configuration (its section laid over the file's).
    config: Config,
    backend: Box<dyn Backend>,
    /// Notified when the board is unplugged with `on_unplug = "exit"`.
    exit: Option<Arc<Notify>>,
    mode: ModeId,
    capture: CaptureSettings,
    display: DisplayMap,
    output: Output,
    info: CameraInfo,
    first_screen: String,
}

/// Opens the backend and the sink of one camera.
fn open_camera(options: &StartOptions, plan: CameraPlan) -> Result<Opened, StartError> {
    let config = &plan.config;
    let (backend, extras) = backend_select::open(config, config.mode)?;
    let kind = backend.kind().to_string();
    let serial = plan
        .serial
        .or_else(|| backend.serial())
        .map(|s| camera_plan::camera_name(&s, &kind))
        .unwrap_or(kind);
    // Several simulated cameras are one model: the serial keeps their
    // calibrations apart.
    // (A board's device names its serial already, and keys its
    // calibrations as when it is alone.)
    let several = config.cameras > 1;
    let device = match several && backend.kind() == BackendName::Sim {
        true => format!("{}, camera {serial}", backend.device()),
        false => backend.device(),
    };
    let mut mode = config.mode;
    if backend.kind() == BackendName::Replay && !options.mode_given {
        if let Some(m) = recorded_mode(config) {
            mode = m;
        }
    }
    let sensor = backend.sensor().clone();
    let capture = backend.settings();
    let chosen = sink_select::open(
        config,
        sensor.width,
        sensor.height,
        capture.frame_rate_hz,
        mode,
        Some(serial.as_str()),
    )?;
    let reasons = chosen.reasons();
    let output = Output::spawn_set(chosen.sinks).map_err(StartError::OutputThread)?;
    let mut sink_info = output.info().clone();
    let first_screen = first_screen(
        &device,
        mode,
        &sink_info,
        output.also(),
        reasons.as_deref(),
        several.then_some(serial.as_str()),
    );
    for also in output.also() {
        sink_info.device = format!("{} + {}", sink_info.device, also.device);
    }
    if let Some(reasons) = reasons {
        sink_info.device = format!("{} [auto: {reasons}]", sink_info.device);
    }
    let info = CameraInfo {
        serial,
        backend: backend.kind(),
        device,
        scene: config.scene,
        sink: sink_info,
        limits: backend.limits(),
        sensor,
        state_dir: calibration_store::state_dir(options.state_dir.as_deref()),
        status: extras.status,
        recording: config.recording,
        lights: backend.lights().map(|l| l.rig),
    };
    Ok(Opened {
        config: plan.config.clone(),
        backend,
        exit: extras.exit,
        mode,
        capture,
        display: display_from(config),
        output,
        info,
        first_screen,
    })
}

/// The frame loop's thread and its command channel.
pub(super) struct FrameLoopHandle {
    pub commands: mpsc::Sender<Command>,
    pub thread: JoinHandle<Option<RecordingWriter>>,
}

/// Starts the frame loop on its own thread, with the stored calibration's
/// H if there is one; returns the D-Bus object that talks to it.
fn start_frame_loop(o: Opened, config: &Config) -> Result<(Camera, FrameLoopHandle), StartError> {
    let (stats_tx, stats_rx) = watch::channel(LoopStats::default());
    let (cal_tx, cal_rx) = watch::channel(Calibration::default());
    let (cmd_tx, cmd_rx) = mpsc::channel::<Command>();
    let mut frame_loop = FrameLoop::new(o.backend, o.mode, o.display, o.output, stats_tx, cal_tx)
        .with_separation(config.separation.live_method());
    if let Some(h) = stored_calibration(&o.info) {
        frame_loop.set_gain(h);
    }
    if o.info.backend == BackendName::Opt8241 {
        match stored_phase_axis(&o.info) {
            Some(axis) => match frame_loop.set_phase_axis(axis) {
                Ok(()) => tracing::info!(
                    angle_deg = axis.angle_rad.to_degrees(),
                    "phase calibration loaded: the difference is the quads projected onto its axis"
                ),
                Err(e) => tracing::warn!("stored phase calibration not applied: {e}"),
            },
            None => tracing::warn!(
                "no phase calibration: the difference is quad 0 alone, which assumes no delay \
                 between the modulation and the LED light; run `sdictl calibrate phase` \
                 (docs/hardware.md, \"Phase\")"
            ),
        }
    }
    let job_progress = frame_loop.job_progress();
    let thread = std::thread::Builder::new()
        .name("sdid-frames".into())
        .spawn(move || frame_loop.run(cmd_rx))
        .map_err(StartError::SpawnFrameLoop)?;
    tracing::debug!(backend = %o.info.backend, device = %o.info.device, mode = o.mode.name(), "frame loop started");
    let camera = Camera::new(
        o.info,
        o.mode,
        o.capture,
        o.display,
        cmd_tx.clone(),
        stats_rx,
        cal_rx,
    )
    .with_job_progress(job_progress);
    let handle = FrameLoopHandle {
        commands: cmd_tx,
        thread,
    };
    Ok((camera, handle))
}

/// The gain and read variance of the calibration stored for this sensor
/// and device, if any and usable.
fn stored_calibration(info: &CameraInfo) -> Option<SkellamMixing> {
    let dir = info.state_dir.as_deref()?;
    let record = calibration_store::load(dir, &info.sensor.model, &info.device)
        .map_err(|e| tracing::warn!("reading the stored calibration in {}: {e}", dir.display()))
        .ok()
        .flatten()?;
    match record.skellam() {
        Ok(h) => {
            tracing::info!(
                gain_dn_per_electron = h.gain_dn_per_electron,
                read_variance_dn2 = h.read_variance_dn2,
                "calibration loaded"
            );
            Some(h)
        }
        Err(e) => {
            tracing::warn!("stored calibration ignored: {e}");
            None
        }
    }
}

/// The phase axis stored for this board, if any and usable.
fn stored_phase_axis(info: &CameraInfo) -> Option<PhaseAxis> {
    let dir = info.state_dir.as_deref()?;
    let record = calibration_store::load_phase(dir, &info.sensor.model, &info.device)
        .map_err(|e| tracing::warn!("reading the stored calibration in {}: {e}", dir.display()))
        .ok()
        .flatten()?;
    record
        .axis()
        .map_err(|e| tracing::warn!("stored phase calibration ignored: {e}"))
        .ok()
}
