//! sdid: the SDI difference-camera daemon.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::Duration;

use clap::Parser;
use sdi_core::mode::ModeId;
use sdi_core::sensor::capture_range;
use sdi_daemon::backend::board::{self as board_backend, BoardBackend, OnUnplug};
use sdi_daemon::backend::opt8241::init::Roi;
use sdi_daemon::backend::opt8241::BoardSelector;
use sdi_daemon::backend::replay::ReplayBackend;
use sdi_daemon::backend::sim::SimBackend;
use sdi_daemon::backend::status::StatusHandle;
use sdi_daemon::backend::{Backend, CaptureSettings};
use sdi_daemon::bus::{self, PrivateBus};
use sdi_daemon::calibration_store;
use sdi_daemon::config::{cli, BackendKind, Config, SensorSpec, SinkKind};
use sdi_daemon::dbus::camera::{Camera, CameraInfo};
use sdi_daemon::dbus::{BUS_NAME, OBJECT_PATH};
use sdi_daemon::frame_loop::{Command, FrameLoop};
use sdi_daemon::modes::{DisplayMap, DisplayRange};
use sdi_daemon::recording::Calibration;
use sdi_daemon::sink::loopback::LoopbackSink;
use sdi_daemon::sink::output::Output;
use sdi_daemon::sink::y4m::Y4mSink;
use sdi_daemon::sink::Sink;
use sdi_daemon::stats::Stats;
use tokio::sync::watch;

/// The SDI difference-camera daemon.
#[derive(Debug, Parser)]
#[command(name = "sdid", version, about)]
struct Args {
    /// Configuration file [default: /etc/sdi/sdid.toml if present].
    #[arg(long)]
    config: Option<PathBuf>,
    /// Serve on the session bus (starts a private one if none exists) instead of the system bus.
    #[arg(long)]
    session: bool,
    /// Serve on the bus at this address.
    #[arg(long, conflicts_with = "session")]
    bus_address: Option<String>,
    /// Frame source: auto (the board if attached, else the simulator), sim, replay or opt8241.
    #[arg(long, value_parser = cli::choice::<BackendKind>())]
    backend: Option<BackendKind>,
    /// Recording to play (implies --backend replay).
    #[arg(long)]
    replay: Option<PathBuf>,
    /// Loop the replayed recording.
    #[arg(long = "loop")]
    looping: bool,
    /// Mode at start.
    #[arg(long, value_parser = cli::choice::<ModeId>())]
    mode: Option<ModeId>,
    /// Simulator sensor: preset (ti, pmd) or a sensor description file (TOML).
    #[arg(long)]
    sensor: Option<SensorSpec>,
    /// Frame rate, Hz [0.1, 240].
    #[arg(long, value_parser = cli::in_range(capture_range::FRAME_RATE_HZ))]
    frame_rate_hz: Option<f64>,
    /// Exposure per frame, us [1, 1e6].
    #[arg(long, value_parser = cli::in_range(capture_range::EXPOSURE_US))]
    exposure_us: Option<f64>,
    /// Modulation frequency, Hz [1e3, 100e6].
    #[arg(long, value_parser = cli::in_range(capture_range::MODULATION_HZ))]
    modulation_hz: Option<f64>,
    /// Output sink: auto (v4l2loopback, else PipeWire, else y4m), loopback,
    /// pipewire or y4m.
    #[arg(long, value_parser = cli::choice::<SinkKind>())]
    sink: Option<SinkKind>,
    /// y4m fallback target: "-" (stdout) or a FIFO path [default: stdout if
    /// it is a pipe, else $XDG_RUNTIME_DIR/sdid-view.y4m].
    #[arg(long)]
    y4m_path: Option<String>,
    /// Where calibrations are kept [default: $STATE_DIRECTORY, else
    /// $XDG_STATE_HOME/sdi, else ~/.local/state/sdi].
    #[arg(long)]
    state_dir: Option<PathBuf>,
}

/// The command line's overrides, already typed; validated with the rest after.
fn apply(args: &Args, c: &mut Config) {
    if let Some(b) = args.backend {
        c.backend = b;
    }
    if let Some(p) = &args.replay {
        c.backend = BackendKind::Replay;
        c.replay.path = Some(p.clone());
    }
    if args.looping {
        c.replay.looping = true;
    }
    if let Some(m) = args.mode {
        c.mode = m;
    }
    if let Some(s) = &args.sensor {
        c.sensor = s.clone();
    }
    c.frame_rate_hz = args.frame_rate_hz.or(c.frame_rate_hz);
    c.exposure_us = args.exposure_us.or(c.exposure_us);
    c.modulation_hz = args.modulation_hz.or(c.modulation_hz);
    if let Some(s) = args.sink {
        c.output.sink = s;
    }
    if let Some(p) = &args.y4m_path {
        c.output.y4m_path = p.clone();
    }
}

fn init_logging() {
    use tracing_subscriber::prelude::*;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let registry = tracing_subscriber::registry().with(filter);
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        if let Ok(j) = tracing_journald::layer() {
            registry
                .with(j.with_syslog_identifier("sdid".into()))
                .init();
            return;
        }
    }
    registry
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                // No colour codes in redirected logs (sdid 2> log.txt).
                .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr())),
        )
        .init();
}

/// What the board backend adds: live status and the on_unplug = "exit" signal.
#[derive(Default)]
struct BoardExtras {
    status: Option<StatusHandle>,
    exit: Option<std::sync::Arc<tokio::sync::Notify>>,
}

fn open_board(c: &Config, mode: ModeId) -> Result<(Box<dyn Backend>, BoardExtras), String> {
    let on_unplug = c.board.on_unplug;
    let roi = c.board.roi.map(|[x, y, width, height]| Roi {
        x,
        y,
        width,
        height,
    });
    let mut b = BoardBackend::open(board_backend::BoardBackendConfig {
        selector: BoardSelector {
            serial: c.board.serial.clone(),
            ..BoardSelector::default()
        },
        board: board_backend::board_config(roi, c.frame_rate_hz, c.exposure_us, c.modulation_hz),
        on_unplug,
        seed: c.seed,
        mode,
    })
    .map_err(|e| e.to_string())?;
    let extras = BoardExtras {
        status: Some(b.status()),
        exit: (on_unplug == OnUnplug::Exit).then(|| b.exit_notify()),
    };
    Ok((Box::new(b), extras))
}

fn build_backend(c: &Config, mode: ModeId) -> Result<(Box<dyn Backend>, BoardExtras), String> {
    match c.backend {
        BackendKind::Opt8241 => open_board(c, mode),
        BackendKind::Auto => {
            let mut sim = c.clone();
            sim.backend = BackendKind::Sim;
            match board_backend::board_attached() {
                Ok(true) => match open_board(c, mode) {
                    Ok(b) => {
                        tracing::info!("backend auto: an OPT8241-CDK is attached; using it");
                        Ok(b)
                    }
                    Err(e) => {
                        tracing::warn!("backend auto: a board is attached but cannot be used ({e}); using the simulator");
                        build_backend(&sim, mode)
                    }
                },
                Ok(false) => {
                    tracing::info!("backend auto: no OPT8241-CDK (USB IDs of udev/board-ids) attached; using the simulator");
                    build_backend(&sim, mode)
                }
                Err(e) => {
                    tracing::info!(
                        "backend auto: cannot look for the board ({e}); using the simulator"
                    );
                    build_backend(&sim, mode)
                }
            }
        }
        BackendKind::Sim => {
            let desc = c.sensor.load().map_err(|e| format!("sensor {e}"))?;
            if let Some(hz) = c.modulation_hz {
                desc.check_modulation_hz(hz).map_err(|e| e.to_string())?;
            }
            if desc.dark_current_electrons_per_us > 0.0 {
                tracing::warn!(
                    "sensor '{}': dark current is not simulated by sdid (sdictl sim adds it)",
                    c.sensor
                );
            }
            let mut p = desc.params();
            p.exposure_us = c.exposure_us.unwrap_or(p.exposure_us);
            p.frame_rate_hz = c.frame_rate_hz.unwrap_or(p.frame_rate_hz);
            p.modulation_hz = c.modulation_hz.unwrap_or(p.modulation_hz);
            Ok((
                Box::new(SimBackend::new(p, mode, c.seed).map_err(|e| e.to_string())?),
                BoardExtras::default(),
            ))
        }
        BackendKind::Replay => {
            let path = c
                .replay
                .path
                .as_ref()
                .ok_or("backend replay needs a recording: --replay FILE")?;
            let mut b = ReplayBackend::open(path, c.replay.looping).map_err(|e| e.to_string())?;
            if let Some(fps) = c.frame_rate_hz {
                let mut s = b.settings();
                s.frame_rate_hz = fps;
                b.configure(&s).map_err(|e| e.to_string())?;
            }
            Ok((Box::new(b), BoardExtras::default()))
        }
    }
}

/// Wraps the backend so `[lights]` follow the mode.
fn with_lights(c: &Config, backend: Box<dyn Backend>) -> Result<Box<dyn Backend>, String> {
    use sdi_daemon::light::{driven, select};
    match select::open(&c.lights).map_err(|e| format!("[lights]: {e}"))? {
        Some(lights) => Ok(Box::new(driven::LitBackend::new(
            backend,
            lights,
            driven::LightSwitch::default(),
        ))),
        None => Ok(backend),
    }
}

#[cfg(feature = "pipewire")]
fn open_pipewire(
    width: usize,
    height: usize,
    fps: f64,
    mode: ModeId,
) -> Result<Box<dyn Sink>, String> {
    use sdi_daemon::sink::pipewire::{PipewireSink, VIEW_NODE};
    let s = PipewireSink::open(width, height, fps, mode).map_err(|e| e.to_string())?;
    tracing::info!(
        device = %s.info().device,
        "publishing as a PipeWire camera: e.g. gst-launch-1.0 pipewiresrc target-object={VIEW_NODE} ! videoconvert ! autovideosink"
    );
    Ok(Box::new(s))
}

#[cfg(not(feature = "pipewire"))]
fn open_pipewire(_: usize, _: usize, _: f64, _: ModeId) -> Result<Box<dyn Sink>, String> {
    Err("sdid was built without the PipeWire sink (cargo feature \"pipewire\")".into())
}

/// The output sink, and for `auto` why it was chosen (shown in the log and
/// in `sdictl status`'s Device).
fn build_sink(
    c: &Config,
    width: usize,
    height: usize,
    fps: f64,
    mode: ModeId,
) -> Result<(Box<dyn Sink>, Option<String>), String> {
    let kind = c.output.sink;
    let auto = kind == SinkKind::Auto;
    let mut passed = Vec::new();
    if auto || kind == SinkKind::Loopback {
        match LoopbackSink::open(&c.output.label, &c.output.data_label, width, height, fps) {
            Ok(s) => {
                tracing::info!(device = %s.info().device, "publishing on v4l2loopback");
                let why = auto.then(|| {
                    format!(
                        "auto: v4l2loopback device labelled \"{}\" found",
                        c.output.label
                    )
                });
                return Ok((Box::new(s), why));
            }
            Err(e) if !auto => return Err(e.to_string()),
            Err(e) => {
                tracing::warn!(
                    "{e}\nNo usable v4l2loopback device labelled \"{}\". To publish a V4L2 camera: sudo apt install v4l2loopback-dkms && sudo {}\nTrying PipeWire, then a y4m stream.",
                    c.output.label,
                    v4l2loopback_glue::modprobe_command(&c.output.label)
                );
                passed.push(format!(
                    "no v4l2loopback device labelled \"{}\"",
                    c.output.label
                ));
            }
        }
    }
    if auto || kind == SinkKind::Pipewire {
        match open_pipewire(width, height, fps, mode) {
            Ok(s) => {
                let why = auto.then(|| format!("auto: {}; PipeWire reachable", passed.join("; ")));
                return Ok((s, why));
            }
            Err(e) if !auto => return Err(e),
            Err(e) => {
                tracing::info!("PipeWire sink unavailable ({e}); falling back to a y4m stream");
                passed.push(e);
            }
        }
    }
    let path = (!c.output.y4m_path.is_empty()).then(|| PathBuf::from(&c.output.y4m_path));
    let sink = Y4mSink::new(path.as_deref(), width, height, fps)
        .map_err(|e| format!("y4m output: {e}"))?;
    let loc = sink.location();
    if loc == "stdout" {
        tracing::info!("streaming y4m on stdout (e.g. sdid ... | ffplay -i -)");
    } else {
        tracing::info!("streaming y4m into the FIFO {loc}: watch with `ffplay {loc}`");
        eprintln!("sdid: view the stream with: ffplay {loc}");
    }
    Ok((
        Box::new(sink),
        auto.then(|| format!("auto: {}", passed.join("; "))),
    ))
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

async fn connect(args: &Args) -> Result<(zbus::Connection, Option<PrivateBus>), String> {
    let mut private = None;
    let builder = if let Some(a) = &args.bus_address {
        zbus::connection::Builder::address(a.as_str())
    } else if args.session {
        let addr = match bus::session_address() {
            Some(a) => a,
            None => {
                let p = PrivateBus::spawn().map_err(|e| {
                    format!("no session bus and cannot start dbus-daemon: {e} (install dbus)")
                })?;
                eprintln!(
                    "sdid: no session bus found; started a private one:\n  export DBUS_SESSION_BUS_ADDRESS='{}'\n(sdictl --session finds it automatically)",
                    p.address
                );
                let a = p.address.clone();
                private = Some(p);
                a
            }
        };
        zbus::connection::Builder::address(addr.as_str())
    } else {
        zbus::connection::Builder::system()
    }
    .map_err(|e| e.to_string())?;
    let conn = builder
        .build()
        .await
        .map_err(|e| format!("connecting to D-Bus: {e}"))?;
    Ok((conn, private))
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

/// Shutdown stays within the unit's TimeoutStopSec (15 s) whatever hangs:
/// releasing the bus name, the frame loop (a source stuck in a read), the
/// recorder (frozen storage). What does not finish in time is abandoned,
/// and the log says what.
const NAME_RELEASE_TIMEOUT: Duration = Duration::from_secs(2);
const FRAME_LOOP_STOP_TIMEOUT: Duration = Duration::from_secs(5);
const RECORDING_FINISH_TIMEOUT: Duration = Duration::from_secs(5);

fn already_owned() -> String {
    format!("{BUS_NAME} is already owned: is another sdid running?")
}

async fn run(args: Args) -> Result<(), String> {
    let (mut config, file) = Config::read(args.config.as_deref()).map_err(|e| e.to_string())?;
    apply(&args, &mut config);
    // Validated once, here, after the command line's overrides.
    let adjusted = config.validate().map_err(|e| match &file {
        Some(path) => format!("{}: {e}", path.display()),
        None => e.to_string(),
    })?;
    for a in adjusted {
        tracing::warn!("configuration: {a}");
    }
    // On the bus, and sure the name is free, before touching the device or
    // a sink: a second sdid must not write into the first one's FIFO or
    // take its board. (The name itself is requested once the object is
    // served, so a client that sees it can call at once.)
    let (conn, private_bus) = connect(&args).await?;
    let owned = zbus::fdo::DBusProxy::new(&conn)
        .await
        .map_err(|e| format!("asking the bus about {BUS_NAME}: {e}"))?
        .name_has_owner(BUS_NAME.try_into().map_err(|e| format!("{e}"))?)
        .await
        .map_err(|e| format!("asking the bus about {BUS_NAME}: {e}"))?;
    if owned {
        return Err(already_owned());
    }
    let mut mode = config.mode;
    let (backend, extras) = build_backend(&config, mode)?;
    let backend = with_lights(&config, backend)?;
    if backend.kind() == "replay" && args.mode.is_none() {
        if let Ok(m) = sdi_daemon::recording::RecordingReader::open(
            config
                .replay
                .path
                .as_deref()
                .unwrap_or(std::path::Path::new("")),
        )
        .map(|r| r.header().mode.clone())
        .map_err(|_| ())
        .and_then(|m| ModeId::from_name(&m).map_err(|_| ()))
        {
            mode = m;
        }
    }
    let display = display_from(&config);
    let separation = config.separation.live_method();
    let sensor = backend.sensor().clone();
    let capture: CaptureSettings = backend.settings();
    let (sink, why) = build_sink(
        &config,
        sensor.width,
        sensor.height,
        capture.frame_rate_hz,
        mode,
    )?;
    let mut output = Output::spawn(sink).map_err(|e| e.to_string())?;
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
        state_dir: calibration_store::state_dir(args.state_dir.as_deref()),
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
        .map_err(|e| e.to_string())?;
    tracing::info!(backend = %info.backend, device = %info.device, mode = mode.name(), "frame loop started");

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
        .map_err(|e| e.to_string())?;
    // The object is served before the name is requested: a client that sees
    // the name can call it at once.
    use zbus::fdo::{RequestNameFlags, RequestNameReply};
    match conn
        .request_name_with_flags(BUS_NAME, RequestNameFlags::DoNotQueue.into())
        .await
        .map_err(|e| format!("requesting {BUS_NAME}: {e}"))?
    {
        RequestNameReply::PrimaryOwner | RequestNameReply::AlreadyOwner => {}
        _ => return Err(already_owned()),
    }
    tracing::info!(name = BUS_NAME, path = OBJECT_PATH, "serving D-Bus API");

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
            tokio::time::sleep(std::time::Duration::from_secs(1)).await;
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
            why = wait_for_signal() => why,
            _ = exit.notified() => "board unplugged and [board] on_unplug = \"exit\"",
        },
        None => wait_for_signal().await,
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
            .map_err(|e| e.to_string())?
            .map_err(|_| "frame loop panicked".to_string())?,
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

fn main() -> ExitCode {
    let args = Args::parse();
    init_logging();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("sdid: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let code = match rt.block_on(run(args)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e}");
            eprintln!("sdid: {e}");
            ExitCode::FAILURE
        }
    };
    // A blocking task abandoned at shutdown (a stuck join or finish) must
    // not hold the exit.
    rt.shutdown_timeout(Duration::from_millis(100));
    code
}
