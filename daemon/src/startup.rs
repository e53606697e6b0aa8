//! Start-up as a library function: opens the backend and the sink from a
//! validated configuration, starts the frame loop, serves the D-Bus API and
//! shuts down in order on SIGTERM/SIGINT/SIGHUP (or when the board is unplugged
//! with `on_unplug = "exit"`). `sdid`'s `main` only parses the command line
//! ([`crate::args`]), installs logging and calls [`run`].

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::Duration;

use tokio::sync::watch;

use crate::backend::{select as backend_select, CaptureSettings};
use crate::bus::{self, BusChoice};
use crate::calibration_store;
use crate::config::Config;
use crate::dbus::camera::{Camera, CameraInfo};
use crate::dbus::{BUS_NAME, OBJECT_PATH};
use crate::frame_loop::{Command, FrameLoop};
use crate::modes::{DisplayMap, DisplayRange, ModeId};
use crate::recording::{Calibration, RecordingReader};
use crate::sink::output::Output;
use crate::sink::select as sink_select;
use crate::sink::SinkInfo;
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
    Config(String),
    #[error("{0}")]
    Backend(String),
    #[error("{0}")]
    Sink(String),
    #[error("{0}")]
    Bus(String),
    #[error("{BUS_NAME} is already owned: is another sdid running?")]
    NameTaken,
    #[error("cannot start the runtime: {0}")]
    Runtime(std::io::Error),
    #[error("{0}")]
    FrameLoop(String),
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
fn first_screen(source: &str, mode: ModeId, sink: &SinkInfo, reasons: Option<&str>) -> String {
    let published = match sink.kind {
        "y4m" => "a y4m stream",
        "pipewire" => "a PipeWire camera",
        _ => "a V4L2 camera (v4l2loopback)",
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
    lines.push(
        "  control: sdictl set-mode depth-edge   (sdictl modes: every mode; sdictl status)".into(),
    );
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
    let config = options.config;
    // On the bus, and sure the name is free, before touching the device or
    // a sink: a second sdid must not write into the first one's FIFO or
    // take its board. (The name itself is requested once the object is
    // served, so a client that sees it can call at once.)
    let (conn, private_bus) = bus::connect(&options.bus).await.map_err(StartError::Bus)?;
    let owned = zbus::fdo::DBusProxy::new(&conn)
        .await
        .map_err(|e| StartError::Bus(format!("asking the bus about {BUS_NAME}: {e}")))?
        .name_has_owner(
            BUS_NAME
                .try_into()
                .map_err(|e| StartError::Bus(format!("{e}")))?,
        )
        .await
        .map_err(|e| StartError::Bus(format!("asking the bus about {BUS_NAME}: {e}")))?;
    if owned {
        return Err(StartError::NameTaken);
    }
    let mut mode = config.mode;
    let (backend, extras) = backend_select::open(&config, mode).map_err(StartError::Backend)?;
    if backend.kind() == "replay" && !options.mode_given {
        if let Some(m) = recorded_mode(&config) {
            mode = m;
        }
    }
    let display = display_from(&config);
    let separation = config.separation.live_method();
    let sensor = backend.sensor().clone();
    let capture: CaptureSettings = backend.settings();
    let chosen = sink_select::open(
        &config,
        sensor.width,
        sensor.height,
        capture.frame_rate_hz,
        mode,
    )
    .map_err(|e| StartError::Sink(e.to_string()))?;
    let reasons = chosen.reasons();
    let mut output = Output::spawn(chosen.sink).map_err(|e| StartError::Sink(e.to_string()))?;
    output.set_mode(mode);
    let mut sink_info = output.info().clone();
    let first_screen = first_screen(&backend.device(), mode, &sink_info, reasons.as_deref());
    if let Some(reasons) = reasons {
        sink_info.device = format!("{} [auto: {reasons}]", sink_info.device);
    }
    let info = CameraInfo {
        backend: backend.kind().into(),
        device: backend.device(),
        scene: config.scene.and_then(|s| s.spec()),
        sink: sink_info,
        limits: backend.limits(),
        sensor: sensor.clone(),
        state_dir: calibration_store::state_dir(options.state_dir.as_deref()),
        status: extras.status,
        recording: config.recording,
    };
    let stored = info.state_dir.as_deref().and_then(|dir| {
        calibration_store::load(dir, &sensor.model, &info.device)
            .map_err(|e| tracing::warn!("reading the stored calibration in {}: {e}", dir.display()))
            .ok()
            .flatten()
    });
    let (stats_tx, stats_rx) = watch::channel(LoopStats::default());
    let (cal_tx, cal_rx) = watch::channel(Calibration::default());
    let (cmd_tx, cmd_rx) = mpsc::channel::<Command>();
    let mut frame_loop = FrameLoop::new(backend, mode, display, output, stats_tx, cal_tx)
        .with_separation(separation);
    if let Some(rec) = stored {
        match rec.skellam() {
            Ok(h) => {
                tracing::info!(
                    gain_dn_per_electron = h.gain_dn_per_electron,
                    read_variance_dn2 = h.read_variance_dn2,
                    "calibration loaded"
                );
                frame_loop.set_gain(h);
            }
            Err(e) => tracing::warn!("stored calibration ignored: {e}"),
        }
    }
    let loop_thread = std::thread::Builder::new()
        .name("sdid-frames".into())
        .spawn(move || frame_loop.run(cmd_rx))
        .map_err(|e| StartError::FrameLoop(e.to_string()))?;
    tracing::debug!(backend = %info.backend, device = %info.device, mode = mode.name(), "frame loop started");

    let camera = Camera::new(
        info,
        mode,
        capture,
        display,
        cmd_tx.clone(),
        stats_rx,
        cal_rx,
    );
    conn.object_server()
        .at(OBJECT_PATH, camera)
        .await
        .map_err(|e| StartError::Bus(e.to_string()))?;
    // The object is served before the name is requested: a client that sees
    // the name can call it at once.
    use zbus::fdo::{RequestNameFlags, RequestNameReply};
    match conn
        .request_name_with_flags(BUS_NAME, RequestNameFlags::DoNotQueue.into())
        .await
        .map_err(|e| match e {
            // zbus reports RequestNameReply::Exists as this error.
            zbus::Error::NameTaken => StartError::NameTaken,
            e => StartError::Bus(format!("requesting {BUS_NAME}: {e}")),
        })? {
        RequestNameReply::PrimaryOwner | RequestNameReply::AlreadyOwner => {}
        _ => return Err(StartError::NameTaken),
    }
    tracing::info!(name = BUS_NAME, path = OBJECT_PATH, "serving D-Bus API");
    // Shown where info is (the default; the tests run sdid at warn).
    if tracing::enabled!(tracing::Level::INFO) {
        eprintln!("{first_screen}");
    }

    // Stats change signals, about once a second while they change (the frame
    // rate decays to 0 when frames stop, without a new frame to say so).
    let stats_conn = conn.clone();
    let stats_task = tokio::spawn(async move {
        let Ok(iface) = stats_conn
            .object_server()
            .interface::<_, Camera>(OBJECT_PATH)
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
    });

    let why = match extras.exit {
        Some(exit) => tokio::select! {
            why = stop => why,
            _ = exit.notified() => "board unplugged and [board] on_unplug = \"exit\"",
        },
        None => stop.await,
    };
    tracing::info!("{why}: shutting down");
    stats_task.abort();
    let recording = match conn
        .object_server()
        .interface::<_, Camera>(OBJECT_PATH)
        .await
    {
        Ok(iface) => iface
            .get()
            .await
            .recording_path()
            .map(|p| p.display().to_string())
            .unwrap_or_default(),
        Err(_) => String::new(),
    };
    if tokio::time::timeout(NAME_RELEASE_TIMEOUT, conn.release_name(BUS_NAME))
        .await
        .is_err()
    {
        tracing::warn!("releasing {BUS_NAME} took over {NAME_RELEASE_TIMEOUT:?}; going on");
    }
    let _ = cmd_tx.send(Command::Shutdown);
    let joined = tokio::time::timeout(
        FRAME_LOOP_STOP_TIMEOUT,
        tokio::task::spawn_blocking(move || loop_thread.join()),
    )
    .await;
    let result = match joined {
        Ok(r) => r
            .map_err(|e| StartError::FrameLoop(e.to_string()))?
            .map_err(|_| StartError::FrameLoop("frame loop panicked".into()))?,
        Err(_) => {
            let lost = if recording.is_empty() {
                String::new()
            } else {
                format!(", and the recording {recording:?} without its end record")
            };
            tracing::error!(
                "the frame loop did not stop within {FRAME_LOOP_STOP_TIMEOUT:?} (the source is stuck); abandoning it{lost}"
            );
            None
        }
    };
    if let Some(rec) = result {
        // within the unit's TimeoutStopSec (15 s), even on frozen storage
        let path = rec.path().display().to_string();
        match tokio::task::spawn_blocking(move || rec.finish_within(RECORDING_FINISH_TIMEOUT)).await
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
    drop(conn);
    drop(private_bus);
    Ok(())
}
