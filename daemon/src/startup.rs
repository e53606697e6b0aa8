//! Start-up as a library function: opens the backend and the sink from a
//! validated configuration, starts the frame loop, serves the D-Bus API and
//! shuts down in order on SIGTERM/SIGINT (or when the board is unplugged
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
use crate::stats::Stats;

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

/// Longest wait for the recorder to finish at shutdown (the unit's
/// TimeoutStopSec is 15 s).
const RECORDING_FINISH_TIMEOUT: Duration = Duration::from_secs(5);

/// Runs sdid on its own runtime until SIGTERM or SIGINT.
pub fn run(options: StartOptions) -> Result<(), StartError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(StartError::Runtime)?;
    rt.block_on(serve(options, wait_for_signal()))
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

async fn wait_for_signal() -> &'static str {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut term), Ok(mut int)) = (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
    ) else {
        std::future::pending::<()>().await;
        return "";
    };
    tokio::select! {
        _ = term.recv() => "SIGTERM",
        _ = int.recv() => "SIGINT",
    }
}

/// Serves until `stop` completes (its value names the reason in the log).
pub async fn serve(
    options: StartOptions,
    stop: impl std::future::Future<Output = &'static str>,
) -> Result<(), StartError> {
    let config = options.config;
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
    let (sink, why) = sink_select::open(
        &config,
        sensor.width,
        sensor.height,
        capture.frame_rate_hz,
        mode,
    )
    .map_err(StartError::Sink)?;
    let mut output = Output::spawn(sink).map_err(|e| StartError::Sink(e.to_string()))?;
    output.set_mode(mode);
    let mut sink_info = output.info().clone();
    if let Some(why) = why {
        tracing::info!(sink = sink_info.kind, "sink {why}");
        sink_info.device = format!("{} [{why}]", sink_info.device);
    }
    let info = CameraInfo {
        backend: backend.kind().into(),
        device: backend.device(),
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
    let (stats_tx, stats_rx) = watch::channel(Stats::default());
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
    tracing::info!(backend = %info.backend, device = %info.device, mode = mode.name(), "frame loop started");

    let (conn, private_bus) = bus::connect(&options.bus).await.map_err(StartError::Bus)?;
    let camera = Camera::new(
        info,
        mode,
        capture,
        display,
        cmd_tx.clone(),
        stats_rx.clone(),
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

    // Stats change signals, about once a second.
    let stats_conn = conn.clone();
    let mut stats_watch = stats_rx;
    let stats_task = tokio::spawn(async move {
        let Ok(iface) = stats_conn
            .object_server()
            .interface::<_, Camera>(OBJECT_PATH)
            .await
        else {
            return;
        };
        loop {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if stats_watch.has_changed().unwrap_or(false) {
                stats_watch.borrow_and_update();
                let cam = iface.get().await;
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
    let _ = conn.release_name(BUS_NAME).await;
    let _ = cmd_tx.send(Command::Shutdown);
    let result = tokio::task::spawn_blocking(move || loop_thread.join())
        .await
        .map_err(|e| StartError::FrameLoop(e.to_string()))?
        .map_err(|_| StartError::FrameLoop("frame loop panicked".into()))?;
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
