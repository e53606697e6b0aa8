//! Start-up as a library function: opens each camera's backend and sinks
//! from a validated configuration ([`camera_plan`]), starts its frame loop,
//! serves it on the D-Bus API (`/org/sdi/CameraN`, listed by the object
//! manager at `/org/sdi`) and
//! shuts down in order on SIGTERM/SIGINT/SIGHUP (or when the board is unplugged
//! with `on_unplug = "exit"`). `sdid`'s `main` only parses the command line
//! ([`crate::args`]), installs logging and calls [`run`].

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::mpsc;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use sdi_config::{Config, ConfigError, Invalid};
use sdi_core::display::{DisplayMap, DisplayRange};
use sdi_core::mode::ModeId;
use sdi_core::quad_phase::PhaseAxis;
use sdi_core::sensor::SkellamMixing;
use sdi_recording::{Calibration, RecordingReader};
use tokio::sync::{watch, Notify};

use crate::backend::select::{self as backend_select, OpenError};
use crate::backend::{Backend, BackendName, CaptureSettings};
use crate::bus::{self, BusChoice, ConnectError, PrivateBus};
use crate::calibration_store;
use crate::camera_plan::{self, CameraPlan};
use crate::dbus::camera::{Camera, CameraInfo};
use crate::dbus::{camera_path, BUS_NAME, CAMERAS_PATH};
use crate::frame_loop::{Command, FrameLoop};
use crate::recorder::RecordingWriter;
use crate::sink::output::Output;
use crate::sink::select as sink_select;
use crate::sink::{SinkError, SinkInfo, SinkKindName};
use crate::stats::LoopStats;

/// Everything sdid needs to start, parsed and validated.
#[derive(Debug, Clone)]
pub struct StartOptions {
    /// The configuration, command-line overrides applied, validated.
    pub config: Config,
    pub bus: BusChoice,
    /// Where calibrations are kept (`None`: the default search).
    pub state_dir: Option<PathBuf>,
    /// The mode was chosen explicitly (a replay otherwise starts in the
    /// recording's mode).
    pub mode_given: bool,
}

/// Why sdid could not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("{0}")]
    Config(#[source] ConfigError),
    #[error("{}{source}", in_file(.file.as_deref()))]
    Invalid {
        /// The configuration file the setting came from, if any.
        file: Option<PathBuf>,
        #[source]
        source: Invalid,
    },
    #[error("{0}")]
    Backend(#[from] OpenError),
    #[error("{0}")]
    Sink(#[from] SinkError),
    #[error("{0}")]
    OutputThread(#[source] std::io::Error),
    #[error("{0}")]
    Connect(#[from] ConnectError),
    #[error("asking the bus about {BUS_NAME}: {0}")]
    OwnerProxy(#[source] zbus::Error),
    #[error("asking the bus about {BUS_NAME}: {0}")]
    AskOwner(#[source] zbus::fdo::Error),
    #[error("{0}")]
    BusName(#[source] zbus::names::Error),
    #[error("{0}")]
    Serve(#[source] zbus::Error),
    #[error("requesting {BUS_NAME}: {0}")]
    RequestName(#[source] zbus::Error),
    #[error("{BUS_NAME} is already owned: is another sdid running?")]
    NameTaken,
    #[error("cannot start the runtime: {0}")]
    Runtime(#[source] std::io::Error),
    #[error("{0}")]
    SpawnFrameLoop(#[source] std::io::Error),
    #[error("{0}")]
    JoinFrameLoop(#[source] tokio::task::JoinError),
    #[error("frame loop panicked")]
    FrameLoopPanicked,
}

/// "FILE: " before a message about a setting read from FILE.
fn in_file(file: Option<&Path>) -> String {
    file.map(|f| format!("{}: ", f.display()))
        .unwrap_or_default()
}

/// Shutdown stays within the unit's TimeoutStopSec (15 s) whatever hangs:
/// releasing the bus name, the frame loop (a source stuck in a read), the
/// recorder (frozen storage). What does not finish in time is abandoned,
/// and the log says what.
const NAME_RELEASE_TIMEOUT: Duration = Duration::from_secs(2);
const FRAME_LOOP_STOP_TIMEOUT: Duration = Duration::from_secs(5);
const RECORDING_FINISH_TIMEOUT: Duration = Duration::from_secs(5);

/// Runs sdid on its own runtime until SIGTERM, SIGINT or SIGHUP.
pub fn run(options: StartOptions) -> Result<(), StartError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(StartError::Runtime)?;
    let result = rt.block_on(serve(options, wait_for_signal()));
    // A blocking task abandoned at shutdown (a stuck join or finish) must
    // not hold the exit.
    rt.shutdown_timeout(Duration::from_millis(100));
    result
}

/// The process exit code for [`run`]'s result; an error is logged and
/// printed on stderr.
pub fn exit_code(result: Result<(), StartError>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e}");
            eprintln!("sdid: {e}");
            ExitCode::FAILURE
        }
    }
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

/// Waits for SIGTERM, SIGINT or SIGHUP. Each shuts down cleanly (a running
/// recording gets its end record): SIGHUP comes when the terminal of
/// `sdid --session` closes; the configuration is read at start only
/// (`systemctl restart sdid` applies a changed one).
async fn wait_for_signal() -> &'static str {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut term), Ok(mut int), Ok(mut hup)) = (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
        signal(SignalKind::hangup()),
    ) else {
        std::future::pending::<()>().await;
        return "";
    };
    tokio::select! {
        _ = term.recv() => "SIGTERM",
        _ = int.recv() => "SIGINT",
        _ = hup.recv() => "SIGHUP",
    }
}

/// Serves until `stop` completes (its value names the reason in the log).
pub async fn serve(
    options: StartOptions,
    stop: impl std::future::Future<Output = &'static str>,
) -> Result<(), StartError> {
    // On the bus, and sure the name is free, before touching the device or
    // a sink: a second sdid must not write into the first one's FIFO or
    // take its board. (The name itself is requested once the object is
    // served, so a client that sees it can call at once.)
    let (conn, private_bus) = connect_unowned(&options.bus).await?;
    conn.object_server()
        .at(CAMERAS_PATH, zbus::fdo::ObjectManager)
        .await
        .map_err(StartError::Serve)?;
    let mut running = Vec::new();
    let mut screens = Vec::new();
    let mut exits = Vec::new();
    let boards = attached_boards(&options.config);
    for (index, plan) in camera_plan::plans(&options.config, &boards)
        .into_iter()
        .enumerate()
    {
        let opened = open_camera(&options, plan)?;
        exits.extend(opened.exit.clone());
        screens.push(opened.first_screen.clone());
        let config = opened.config.clone();
        let (camera, frames) = start_frame_loop(opened, &config)?;
        let path = camera_path(index);
        conn.object_server()
            .at(path.as_str(), camera)
            .await
            .map_err(StartError::Serve)?;
        tracing::info!(name = BUS_NAME, path, "serving D-Bus API");
        running.push(Running { path, frames });
    }
    request_name(&conn).await?;
    // Shown where info is (the default; the tests run sdid at warn).
    if tracing::enabled!(tracing::Level::INFO) {
        eprintln!("{}", screens.join("\n"));
    }
    let stats_tasks: Vec<_> = running
        .iter()
        .map(|r| tokio::spawn(emit_stats(conn.clone(), r.path.clone())))
        .collect();
    let why = wait_for_stop(stop, exits).await;
    tracing::info!("{why}: shutting down");
    stats_tasks.iter().for_each(|t| t.abort());
    shut_down(&conn, running).await?;
    drop(conn);
    drop(private_bus);
    Ok(())
}

/// The serials of the boards attached, when the configuration may serve
/// every one (the board or auto backend, no `[board] serial`).
fn attached_boards(c: &Config) -> Vec<String> {
    use sdi_config::BackendKind;
    if !matches!(c.backend, BackendKind::Opt8241 | BackendKind::Auto) || c.board.serial.is_some() {
        return Vec::new();
    }
    crate::backend::board::attached_serials()
        .map_err(|e| tracing::debug!("listing the boards: {e}"))
        .unwrap_or_default()
}

/// A served camera: its object path and frame loop.
struct Running {
    path: String,
    frames: FrameLoopHandle,
}

/// Connects to the bus and checks that no one owns sdid's name yet.
async fn connect_unowned(
    choice: &BusChoice,
) -> Result<(zbus::Connection, Option<PrivateBus>), StartError> {
    let (conn, private_bus) = bus::connect(choice).await?;
    let owned = zbus::fdo::DBusProxy::new(&conn)
        .await
        .map_err(StartError::OwnerProxy)?
        .name_has_owner(BUS_NAME.try_into().map_err(StartError::BusName)?)
        .await
        .map_err(StartError::AskOwner)?;
    if owned {
        return Err(StartError::NameTaken);
    }
    Ok((conn, private_bus))
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
    let serial = plan
        .serial
        .or_else(|| backend.serial())
        .unwrap_or_else(|| backend.kind().to_string());
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
struct FrameLoopHandle {
    commands: mpsc::Sender<Command>,
    thread: JoinHandle<Option<RecordingWriter>>,
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

/// Requests the name once every camera is served: a client that sees the
/// name can call it at once.
async fn request_name(conn: &zbus::Connection) -> Result<(), StartError> {
    use zbus::fdo::{RequestNameFlags, RequestNameReply};
    match conn
        .request_name_with_flags(BUS_NAME, RequestNameFlags::DoNotQueue.into())
        .await
        .map_err(|e| match e {
            // zbus reports RequestNameReply::Exists as this error.
            zbus::Error::NameTaken => StartError::NameTaken,
            e => StartError::RequestName(e),
        })? {
        RequestNameReply::PrimaryOwner | RequestNameReply::AlreadyOwner => Ok(()),
        _ => Err(StartError::NameTaken),
    }
}

/// Emits the Stats change signal about once a second while they change
/// (the frame rate decays to 0 when frames stop, without a new frame to
/// say so).
async fn emit_stats(conn: zbus::Connection, path: String) {
    let Ok(iface) = conn
        .object_server()
        .interface::<_, Camera>(path.as_str())
        .await
    else {
        return;
    };
    let mut last = None;
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let cam = iface.get().await;
        let now = cam.current_stats();
        if last.as_ref() != Some(&now) {
            last = Some(now);
            let _ = cam.stats_changed(iface.signal_emitter()).await;
        }
    }
}

/// Waits for `stop` or, with `on_unplug = "exit"`, a board's unplugging;
/// the reason, for the log.
async fn wait_for_stop(
    stop: impl std::future::Future<Output = &'static str>,
    exits: Vec<Arc<Notify>>,
) -> &'static str {
    if exits.is_empty() {
        return stop.await;
    }
    // Any board's: each one's notice wakes one waiter (a stored permit).
    let any = Arc::new(Notify::new());
    for exit in exits {
        let any = any.clone();
        tokio::spawn(async move {
            exit.notified().await;
            any.notify_one();
        });
    }
    tokio::select! {
        why = stop => why,
        _ = any.notified() => "board unplugged and [board] on_unplug = \"exit\"",
    }
}

/// Releases the name, then stops each camera's frame loop and finishes
/// its running recording, each within its timeout.
async fn shut_down(conn: &zbus::Connection, running: Vec<Running>) -> Result<(), StartError> {
    let mut recordings = Vec::new();
    for r in &running {
        recordings.push(recording_label(conn, &r.path).await);
    }
    if tokio::time::timeout(NAME_RELEASE_TIMEOUT, conn.release_name(BUS_NAME))
        .await
        .is_err()
    {
        tracing::warn!("releasing {BUS_NAME} took over {NAME_RELEASE_TIMEOUT:?}; going on");
    }
    // Every loop is told first, so the cameras stop together.
    for r in &running {
        let _ = r.frames.commands.send(Command::Shutdown);
    }
    for (r, recording) in running.into_iter().zip(recordings) {
        if let Some(recorder) = stop_frame_loop(r.frames, &recording).await? {
            finish_recording(recorder).await;
        }
    }
    Ok(())
}

/// The file being recorded to, "" when none.
async fn recording_label(conn: &zbus::Connection, path: &str) -> String {
    match conn.object_server().interface::<_, Camera>(path).await {
        Ok(iface) => iface
            .get()
            .await
            .recording_path()
            .map(|p| p.display().to_string())
            .unwrap_or_default(),
        Err(_) => String::new(),
    }
}

/// Stops the frame loop; its recorder, if one runs, for the caller to
/// finish. A loop that does not stop in time is abandoned (`None`).
async fn stop_frame_loop(
    frames: FrameLoopHandle,
    recording: &str,
) -> Result<Option<RecordingWriter>, StartError> {
    let _ = frames.commands.send(Command::Shutdown);
    let thread = frames.thread;
    let joined = tokio::time::timeout(
        FRAME_LOOP_STOP_TIMEOUT,
        tokio::task::spawn_blocking(move || thread.join()),
    )
    .await;
    match joined {
        Ok(r) => r
            .map_err(StartError::JoinFrameLoop)?
            .map_err(|_| StartError::FrameLoopPanicked),
        Err(_) => {
            let lost = if recording.is_empty() {
                String::new()
            } else {
                format!(", and the recording {recording:?} without its end record")
            };
            tracing::error!(
                "the frame loop did not stop within {FRAME_LOOP_STOP_TIMEOUT:?} (the source is stuck); abandoning it{lost}"
            );
            Ok(None)
        }
    }
}

/// Finishes the recording within the unit's TimeoutStopSec, even on
/// frozen storage.
async fn finish_recording(recorder: RecordingWriter) {
    let path = recorder.path().display().to_string();
    match tokio::task::spawn_blocking(move || recorder.finish_within(RECORDING_FINISH_TIMEOUT))
        .await
    {
        Ok(Ok(s)) => tracing::info!(
            path,
            frames = s.frames,
            dropped = s.dropped,
            "recording finalized"
        ),
        Ok(Err(e)) => tracing::error!(path, "recording abandoned at shutdown: {e}"),
        Err(e) => tracing::error!(path, "recording abandoned at shutdown: {e}"),
    }
}
