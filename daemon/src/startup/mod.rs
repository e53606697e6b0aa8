//! Start-up as a library function: brings up each camera of a validated
//! configuration ([`crate::camera_plan`], [`camera`]) on the D-Bus API
//! (`/org/sdi/CameraN`, listed by the object manager at `/org/sdi`), and
//! boards plugged in later ([`arrivals`]); shuts down in order on
//! SIGTERM/SIGINT/SIGHUP or when a board is unplugged with `on_unplug =
//! "exit"` ([`shutdown`]). `sdid`'s `main` only parses the command line
//! ([`crate::args`]), installs logging and calls [`run`].

mod arrivals;
mod camera;
mod shutdown;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use sdi_config::{Config, ConfigError, Invalid};
use tokio::sync::{Mutex, Notify};

use crate::backend::select::OpenError;
use crate::bus::{self, BusChoice, ConnectError, PrivateBus};
use crate::camera_plan;
use crate::dbus::camera::Camera;
use crate::dbus::{BUS_NAME, CAMERAS_PATH};
use crate::sink::SinkError;
use camera::Served;

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
    #[error("opening a camera: {0}")]
    OpenTask(#[source] tokio::task::JoinError),
    #[error("frame loop panicked")]
    FrameLoopPanicked,
}

/// "FILE: " before a message about a setting read from FILE.
fn in_file(file: Option<&Path>) -> String {
    file.map(|f| format!("{}: ", f.display()))
        .unwrap_or_default()
}

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
    // On the bus, and sure the name is free, before touching a device or
    // a sink: a second sdid must not write into the first one's FIFO or
    // take its board. (The name itself is requested once the objects are
    // served, so a client that sees it can call at once.)
    let (conn, private_bus) = connect_unowned(&options.bus).await?;
    conn.object_server()
        .at(CAMERAS_PATH, zbus::fdo::ObjectManager)
        .await
        .map_err(StartError::Serve)?;
    let exits = Arc::new(Notify::new());
    let mut served = Served::default();
    let boards = arrivals::attached_boards(&options.config);
    let mut screens = Vec::new();
    let plans = camera_plan::plans(&options.config, &boards);
    // Boards served by serial (each camera pinned to its board): one
    // plugged in later is a camera too.
    let watch_boards = camera_plan::serves_boards_by_serial(&options.config)
        && plans.iter().all(|p| p.config.board.serial.is_some());
    // One of several cameras that cannot be opened (a board that fails)
    // costs the others nothing; sdid stops only when none opens.
    let several = plans.len() > 1;
    let mut first_error = None;
    for plan in plans {
        let serial = plan.serial.clone().unwrap_or_default();
        match camera::serve_camera(&conn, &options, plan, &mut served, &exits).await {
            Ok(screen) => screens.push(screen),
            Err(e) if several => {
                tracing::error!("camera {serial} not served: {e}");
                first_error.get_or_insert(e);
            }
            Err(e) => return Err(e),
        }
    }
    if let (true, Some(e)) = (served.cameras.is_empty(), first_error) {
        return Err(e);
    }
    request_name(&conn).await?;
    // Shown where info is (the default; the tests run sdid at warn).
    if tracing::enabled!(tracing::Level::INFO) {
        eprintln!("{}", screens.join("\n"));
    }
    let served = Arc::new(Mutex::new(served));
    let watcher = watch_boards.then(|| {
        tokio::spawn(arrivals::watch(
            conn.clone(),
            options.clone(),
            served.clone(),
            exits.clone(),
        ))
    });
    let why = shutdown::wait_for_stop(stop, &exits).await;
    tracing::info!("{why}: shutting down");
    if let Some(w) = watcher {
        w.abort();
    }
    let cameras = std::mem::take(&mut served.lock().await.cameras);
    shutdown::shut_down(&conn, cameras).await?;
    drop(conn);
    drop(private_bus);
    Ok(())
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
