//! Online subcommands: talk to `sdid` over D-Bus (`org.sdi.Camera1`)
//! through the typed proxy of `sdi_api`, one module per group of commands.

pub(crate) mod cameras;
mod doctor;
mod export;
mod files;
mod long_call;
mod monitor;
pub(crate) mod new_file;
mod settings;
mod status;
mod units;
pub(crate) mod wire_json;

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use clap::{Args, Subcommand};
use sdi_api::Camera1Proxy;

use crate::exit::CliError;

/// How to reach the daemon; global flags.
#[derive(Debug, Clone, Args)]
pub struct BusArgs {
    /// Use the session bus (or the private bus `sdid --session` started) instead of the system bus.
    #[arg(long, global = true)]
    pub session: bool,
    /// Use the bus at this address.
    #[arg(long, global = true, value_name = "ADDRESS")]
    pub bus_address: Option<String>,
    /// Machine-readable JSON on stdout.
    #[arg(long, global = true)]
    pub json: bool,
    /// The camera to control, by serial (`sdictl list`) [default: the only one].
    #[arg(long, global = true, value_name = "SERIAL")]
    pub camera: Option<String>,
}

/// Subcommands that control a running daemon.
#[derive(Debug, Subcommand)]
pub enum OnlineCommand {
    /// List the cameras sdid serves: serial, backend, mode, device and nodes.
    List,
    /// Show mode, setup, device, settings and statistics.
    Status,
    /// List the modes.
    Modes,
    /// Switch mode (takes effect on the next frame).
    SetMode { mode: String },
    /// Print one property (Mode, ExposureUs, FrameRate, Stats, ...).
    Get { property: String },
    /// Change a setting (takes effect on the next frame).
    Set {
        #[arg(help = format!("One of: {}", sdi_api::Setting::names().join(", ")))]
        property: String,
        #[arg(allow_hyphen_values = true)]
        value: String,
    },
    /// Average FRAMES frames with the sources off into the dark frame.
    DarkFrame {
        #[arg(default_value_t = 32)]
        frames: u32,
    },
    /// Calibrate: dark frame, read noise and fixed pattern, then photon transfer
    /// (gain and read variance from LS1 at 5 exposures; stored, used for separation).
    /// `sdictl calibrate phase`: the board's phase axis.
    #[command(args_conflicts_with_subcommands = true)]
    Calibrate {
        #[arg(default_value_t = 64)]
        frames: u32,
        #[command(subcommand)]
        what: Option<CalibrateWhat>,
    },
    /// Record raw frames to a new .sdirec file (stops after --seconds if given).
    ///
    /// sdictl creates the file as you and passes the daemon its descriptor,
    /// so any place you may write works, even though the service cannot see
    /// home directories or /tmp.
    Record {
        path: PathBuf,
        #[arg(long)]
        seconds: Option<f64>,
        /// Let the daemon create PATH itself: only a new file directly in its
        /// state directory (/var/lib/sdi/NAME for the service).
        #[arg(long)]
        by_path: bool,
    },
    /// Stop the recording.
    Stop,
    /// Save the latest frame: .png (as displayed) or .npy (signed DN).
    ///
    /// sdictl creates the file as you (whole or not at all) and passes the
    /// daemon its descriptor.
    Snapshot {
        path: PathBuf,
        /// Let the daemon create PATH itself: only a new file directly in its
        /// state directory (/var/lib/sdi/NAME for the service).
        #[arg(long)]
        by_path: bool,
    },
    /// Live viewer and control panel in the browser (127.0.0.1, a random
    /// port and token; Ctrl-C to stop).
    View(crate::view::ViewArgs),
    /// Live frame rate and latency (Ctrl-C to stop).
    Monitor {
        /// Stop after this many updates.
        #[arg(long)]
        count: Option<u64>,
    },
    /// Convert a recording to .npy (frames x height x width, float32 DN); offline.
    Export { recording: PathBuf, out: PathBuf },
    /// Check what the SDI camera needs (module, nodes, Secure Boot, groups,
    /// daemon, board, PipeWire) and print the fix for each problem; exit
    /// status 0 only when nothing blocks.
    Doctor {
        /// Read sysfs/procfs under this directory (tests).
        #[arg(long, hide = true, default_value = "/")]
        sysroot: PathBuf,
    },
}

/// What `sdictl calibrate` calibrates besides gain and read noise.
#[derive(Debug, Subcommand)]
pub enum CalibrateWhat {
    /// The OPT8241-CDK's phase axis: LS1 alone lit (sdid lights it through
    /// [lights]; without a light rig, cover LS2 first), the quads' phase
    /// measured, stored and used from then on (docs/hardware.md, "Phase").
    Phase {
        /// Frames of LS1 alone to sum.
        #[arg(long, default_value_t = 16)]
        frames: u32,
    },
}

/// Runs an online subcommand and maps the outcome to an exit status.
pub fn run(cmd: OnlineCommand, bus: BusArgs) -> ExitCode {
    let json = bus.json;
    let result = match cmd {
        OnlineCommand::Export { recording, out } => export::run(&recording, &out, json),
        OnlineCommand::Doctor { sysroot } => return doctor::run(&bus, &sysroot),
        cmd => match tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        {
            Ok(rt) => rt.block_on(run_async(cmd, &bus)),
            Err(e) => Err(CliError::Runtime(e.to_string())),
        },
    };
    crate::exit::report(result, json)
}

/// One call per subcommand that talks to sdid.
async fn run_async(cmd: OnlineCommand, bus: &BusArgs) -> Result<(), CliError> {
    let json = bus.json;
    if let OnlineCommand::List = cmd {
        return cameras::run(&connect_bus(bus).await?, json).await;
    }
    let cam = match &cmd {
        // The viewer starts on the first camera when none is named.
        OnlineCommand::View(_) if bus.camera.is_none() => {
            cameras::first(&connect_bus(bus).await?).await?
        }
        _ => connect(bus).await?,
    };
    match cmd {
        OnlineCommand::Status => status::run(&cam, json).await,
        OnlineCommand::Modes => settings::modes(&cam, json).await,
        OnlineCommand::SetMode { mode } => settings::set_mode(&cam, &mode, json).await,
        OnlineCommand::Get { property } => settings::get(&cam, &property, json).await,
        OnlineCommand::Set { property, value } => {
            settings::set(&cam, &property, &value, json).await
        }
        OnlineCommand::DarkFrame { frames } => long_call::dark_frame(&cam, frames, json).await,
        OnlineCommand::Calibrate {
            what: Some(CalibrateWhat::Phase { frames }),
            ..
        } => long_call::calibrate_phase(&cam, frames, json).await,
        OnlineCommand::Calibrate { frames, what: None } => {
            long_call::calibrate(&cam, frames, json).await
        }
        OnlineCommand::Record {
            path,
            seconds,
            by_path,
        } => files::record(&cam, &path, seconds, by_path, json).await,
        OnlineCommand::Stop => files::stop(&cam, json).await,
        OnlineCommand::Snapshot { path, by_path } => {
            files::snapshot(&cam, &path, by_path, json).await
        }
        OnlineCommand::Monitor { count } => monitor::run(&cam, count, json).await,
        OnlineCommand::View(args) => {
            // The page picks among several; it starts on the one named.
            let chosen = Arc::new(std::sync::Mutex::new(Some(cam.serial().await?)));
            let (bus, serial) = (bus.clone(), chosen.clone());
            let connect = Box::new(move || {
                let mut bus = bus.clone();
                bus.camera = serial.lock().ok().and_then(|s| s.clone());
                Box::pin(async move { connect(&bus).await }) as _
            });
            crate::view::run(cam, connect, chosen, args).await
        }
        // Handled by `run` before a bus is needed, or above.
        OnlineCommand::Export { .. } | OnlineCommand::Doctor { .. } | OnlineCommand::List => Ok(()),
    }
}

fn bus_address(bus: &BusArgs) -> Option<String> {
    if let Some(a) = &bus.bus_address {
        return Some(a.clone());
    }
    if !bus.session {
        return None;
    }
    sdi_api::bus::session_or_private_address()
}

/// Longest sdictl waits for the bus to accept the connection.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// The camera `--camera` names (or the only one), on the bus of `bus`.
async fn connect(bus: &BusArgs) -> Result<Camera1Proxy<'static>, CliError> {
    let conn = connect_bus(bus).await?;
    cameras::chosen(&conn, bus.camera.as_deref()).await
}

/// The bus `bus` names.
pub(crate) async fn connect_bus(bus: &BusArgs) -> Result<zbus::Connection, CliError> {
    let builder = match bus_address(bus) {
        Some(a) => zbus::connection::Builder::address(a.as_str()),
        None if bus.session => {
            return Err(CliError::Unreachable(
                "no session bus found (DBUS_SESSION_BUS_ADDRESS unset) and no private bus of sdid --session".into(),
            ))
        }
        None => zbus::connection::Builder::system(),
    }
    .map_err(|e| CliError::Unreachable(e.to_string()))?;
    tokio::time::timeout(CONNECT_TIMEOUT, builder.build())
        .await
        .map_err(|_| CliError::Unreachable("timed out connecting to the bus".into()))?
        .map_err(CliError::Connect)
}
