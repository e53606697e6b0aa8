//! Online subcommands: talk to `sdid` over D-Bus (`org.sdi.Camera1`).

mod doctor;
mod errors;
mod export;
mod new_file;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Args, Subcommand};
use futures_util::StreamExt;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{json, Value as Json};
use zbus::zvariant::OwnedValue;

use crate::stdout::outln;
pub use errors::OnlineError;
use new_file::NewFile;
use sdi_api::{Camera1Proxy, SdiError};
use zbus::zvariant::Fd;

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
}

/// Subcommands that control a running daemon.
#[derive(Debug, Subcommand)]
pub enum OnlineCommand {
    /// Show mode, setup, device, settings and statistics.
    Status,
    /// List the modes.
    Modes,
    /// Switch mode (takes effect on the next frame).
    SetMode { mode: String },
    /// Print one property (Mode, ExposureUs, FrameRate, Stats, ...).
    Get { property: String },
    /// Change a setting: exposure-us, frame-rate, modulation-hz, colormap, range, mode.
    Set {
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
    Calibrate {
        #[arg(default_value_t = 64)]
        frames: u32,
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
            Err(e) => Err(OnlineError::Failed(e.to_string())),
        },
    };
    errors::report(result, json)
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

async fn connect(bus: &BusArgs) -> Result<Camera1Proxy<'static>, OnlineError> {
    let builder = match bus_address(bus) {
        Some(a) => zbus::connection::Builder::address(a.as_str()),
        None if bus.session => {
            return Err(OnlineError::Unreachable(
                "no session bus found (DBUS_SESSION_BUS_ADDRESS unset) and no private bus of sdid --session".into(),
            ))
        }
        None => zbus::connection::Builder::system(),
    }
    .map_err(|e| OnlineError::Unreachable(e.to_string()))?;
    let conn = tokio::time::timeout(Duration::from_secs(10), builder.build())
        .await
        .map_err(|_| OnlineError::Unreachable("timed out connecting to the bus".into()))?
        .map_err(|e| OnlineError::Unreachable(format!("cannot connect to the bus: {e}")))?;
    Ok(Camera1Proxy::new(&conn).await?)
}

fn to_json(v: &OwnedValue) -> Json {
    use zbus::zvariant::Value;
    match &**v {
        Value::U8(x) => json!(x),
        Value::Bool(x) => json!(x),
        Value::I16(x) => json!(x),
        Value::U16(x) => json!(x),
        Value::I32(x) => json!(x),
        Value::U32(x) => json!(x),
        Value::I64(x) => json!(x),
        Value::U64(x) => json!(x),
        Value::F64(x) => json!(x),
        Value::Str(s) => json!(s.as_str()),
        other => match OwnedValue::try_from(other.try_clone().unwrap_or(Value::U8(0))) {
            Ok(o) => match Vec::<String>::try_from(o) {
                Ok(list) => json!(list),
                Err(_) => match HashMap::<String, String>::try_from(
                    v.try_clone()
                        .map_err(|_| ())
                        .unwrap_or_else(|_| OwnedValue::from(0u8)),
                ) {
                    Ok(map) => json!(map),
                    Err(_) => match HashMap::<String, OwnedValue>::try_from(
                        v.try_clone().unwrap_or_else(|_| OwnedValue::from(0u8)),
                    ) {
                        Ok(map) => {
                            Json::Object(map.iter().map(|(k, v)| (k.clone(), to_json(v))).collect())
                        }
                        Err(_) => json!(other.to_string()),
                    },
                },
            },
            Err(_) => json!(other.to_string()),
        },
    }
}

fn dict_json(d: &HashMap<String, OwnedValue>) -> Json {
    Json::Object(d.iter().map(|(k, v)| (k.clone(), to_json(v))).collect())
}

/// A typed `a{sv}` reply as the dictionary it is on the wire, so it prints
/// by its D-Bus keys without a second list of its fields here.
fn wire_dict<T: serde::Serialize + zbus::zvariant::Type>(
    reply: &T,
) -> Result<HashMap<String, OwnedValue>, OnlineError> {
    let ctxt = zbus::zvariant::serialized::Context::new_dbus(zbus::zvariant::LE, 0);
    let bytes = zbus::zvariant::to_bytes(ctxt, reply)
        .map_err(|e| OnlineError::Failed(format!("encoding the reply: {e}")))?;
    let (dict, _) = bytes
        .deserialize::<HashMap<String, OwnedValue>>()
        .map_err(|e| OnlineError::Failed(format!("decoding the reply: {e}")))?;
    Ok(dict)
}

async fn all_properties(
    cam: &Camera1Proxy<'_>,
) -> Result<serde_json::Map<String, Json>, OnlineError> {
    let props = zbus::fdo::PropertiesProxy::builder(cam.inner().connection())
        .destination(cam.inner().destination().to_owned())?
        .path(cam.inner().path().to_owned())?
        .build()
        .await?;
    let iface = zbus::names::InterfaceName::from_static_str_unchecked("org.sdi.Camera1");
    let all = props.get_all(iface).await.map_err(zbus::Error::from)?;
    Ok(all.iter().map(|(k, v)| (k.clone(), to_json(v))).collect())
}

/// Accepts "exposure-us", "ExposureUs", "exposure_us".
fn property_name(name: &str) -> String {
    name.split(['-', '_'])
        .map(|w| {
            let mut c = w.chars();
            match c.next() {
                Some(f) => f.to_uppercase().chain(c).collect::<String>(),
                None => String::new(),
            }
        })
        .collect()
}

fn absolute(path: &Path) -> Result<String, OnlineError> {
    let p = if path.is_absolute() {
        path.to_owned()
    } else {
        std::env::current_dir()
            .map_err(|e| OnlineError::Failed(e.to_string()))?
            .join(path)
    };
    p.to_str()
        .map(str::to_owned)
        .ok_or_else(|| OnlineError::Invalid(format!("{} is not valid UTF-8", p.display())))
}

/// The lower-case extension of `path` if it is one of `allowed`.
fn output_extension(path: &str, allowed: &[&str]) -> Result<String, OnlineError> {
    let ext = Path::new(path)
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if allowed.contains(&ext.as_str()) {
        Ok(ext)
    } else {
        Err(OnlineError::Invalid(format!(
            "{path}: the extension must be one of .{}",
            allowed.join(", .")
        )))
    }
}

/// Creates the recording as the calling user and starts the daemon writing
/// into its descriptor; the file gets its name once the daemon has accepted
/// it (the header is written by then, and the format survives a crash).
async fn start_recording_to_fd(cam: &Camera1Proxy<'_>, path: &str) -> Result<(), OnlineError> {
    output_extension(path, &["sdirec"])?;
    let out = NewFile::create(Path::new(path))?;
    cam.start_recording_to_fd(Fd::from(out.file()), path)
        .await?;
    if let Err(e) = out.commit() {
        // Nothing may record into a file that has no name.
        let _ = cam.stop_recording().await;
        return Err(e);
    }
    Ok(())
}

fn parse_f64(prop: &str, v: &str) -> Result<f64, OnlineError> {
    v.parse::<f64>()
        .map_err(|_| OnlineError::Invalid(format!("{prop}: '{v}' is not a number")))
}

fn bar(len: u64, msg: &str, json: bool) -> ProgressBar {
    if json {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}") {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(msg.to_owned());
    pb
}

/// Runs a long call while a progress bar advances at the camera's frame rate.
async fn with_progress<T>(
    cam: &Camera1Proxy<'_>,
    frames: u32,
    msg: &str,
    json: bool,
    call: impl std::future::Future<Output = Result<T, SdiError>>,
) -> Result<T, OnlineError> {
    let fps = cam.frame_rate().await.unwrap_or(30.0).max(0.1);
    let pb = bar(frames as u64, msg, json);
    let start = Instant::now();
    tokio::pin!(call);
    let mut tick = tokio::time::interval(Duration::from_millis(100));
    let r = loop {
        tokio::select! {
            r = &mut call => break r,
            _ = tick.tick() => pb.set_position(((start.elapsed().as_secs_f64() * fps) as u64).min(frames as u64)),
        }
    };
    pb.finish_and_clear();
    Ok(r?)
}

fn print_dict(d: &HashMap<String, OwnedValue>, json: bool) -> Result<(), OnlineError> {
    if json {
        outln!("{}", dict_json(d))?;
    } else {
        let mut keys: Vec<_> = d.keys().collect();
        keys.sort();
        for k in keys {
            outln!("{k}: {}", to_json(&d[k]))?;
        }
    }
    Ok(())
}

/// The simulator's light-travel warning for the scene it shows (the mode's
/// own, or the one `sdid --scene` fixed, named in Device) at the current
/// modulation frequency. None on other backends: a real scene's depth is
/// not known to sdid.
fn light_travel_warning(p: &serde_json::Map<String, Json>) -> Option<String> {
    if p.get("Backend")?.as_str()? != "sim" {
        return None;
    }
    let hz = p.get("ModulationHz")?.as_f64()?;
    let device = p.get("Device")?.as_str()?;
    let scene = match device.split_once(", scene ") {
        Some((_, rest)) => {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                .collect();
            sdi_core::scene::SceneSpec::from_name(&name)?
        }
        None => p
            .get("Mode")?
            .as_str()?
            .parse::<sdi_core::mode::ModeId>()
            .ok()?
            .default_scene(),
    };
    sdi_core::simulator::light_travel::light_travel_warning(&scene, hz)
}

async fn run_async(cmd: OnlineCommand, bus: &BusArgs) -> Result<(), OnlineError> {
    let json = bus.json;
    let cam = connect(bus).await?;
    match cmd {
        OnlineCommand::Status => {
            let p = all_properties(&cam).await?;
            if json {
                outln!("{}", Json::Object(p))?;
            } else {
                for key in [
                    "Mode",
                    "Setup",
                    "Backend",
                    "Device",
                    "Format",
                    "Width",
                    "Height",
                    "FrameRate",
                    "ExposureUs",
                    "ModulationHz",
                    "Colormap",
                    "Range",
                    "Recording",
                    "Stats",
                ] {
                    if let Some(v) = p.get(key) {
                        outln!("{key:>13}: {v}")?;
                    }
                }
                if let Some(w) = light_travel_warning(&p) {
                    outln!("{:>13}: {w}", "Warning")?;
                }
            }
        }
        OnlineCommand::Modes => {
            let p = all_properties(&cam).await?;
            let modes = p.get("Modes").cloned().unwrap_or(Json::Null);
            let current = p.get("Mode").cloned().unwrap_or(Json::Null);
            if json {
                outln!("{}", json!({"modes": modes, "current": current}))?;
            } else if let Json::Array(list) = modes {
                for m in list {
                    let mark = if m == current { "*" } else { " " };
                    outln!("{mark} {}", m.as_str().unwrap_or(""))?;
                }
            }
        }
        OnlineCommand::SetMode { mode } => {
            let (sequence, timestamp_us) = cam.set_mode(&mode).await?;
            if json {
                outln!(
                    "{}",
                    json!({"mode": mode, "first_sequence": sequence, "first_timestamp_us": timestamp_us})
                )?;
            } else {
                outln!("{mode} from frame {sequence} (timestamp {timestamp_us} us)")?;
            }
        }
        OnlineCommand::Get { property } => {
            let name = property_name(&property);
            let p = all_properties(&cam).await?;
            let v = p.get(&name).ok_or_else(|| {
                let mut names: Vec<_> = p.keys().cloned().collect();
                names.sort();
                OnlineError::Invalid(format!(
                    "unknown property '{property}'; properties: {}",
                    names.join(", ")
                ))
            })?;
            if json {
                outln!("{}", json!({ name: v }))?;
            } else {
                match v {
                    Json::String(s) => outln!("{s}")?,
                    other => outln!("{other}")?,
                }
            }
        }
        OnlineCommand::Set { property, value } => {
            let name = property_name(&property);
            let (sequence, timestamp_us) = match name.as_str() {
                "Mode" => cam.set_mode(&value).await?,
                "ExposureUs" => cam.set_exposure_us(parse_f64(&name, &value)?).await?,
                "FrameRate" | "FrameRateHz" => cam.set_frame_rate(parse_f64(&name, &value)?).await?,
                "ModulationHz" => cam.set_modulation_hz(parse_f64(&name, &value)?).await?,
                "Colormap" => cam.set_colormap(&value).await?,
                "Range" => cam.set_range(parse_f64(&name, &value)?).await?,
                _ => {
                    return Err(OnlineError::Invalid(format!(
                        "'{property}' cannot be set; settable: mode, exposure-us, frame-rate, modulation-hz, colormap, range"
                    )))
                }
            };
            if json {
                outln!(
                    "{}",
                    json!({ name: value, "first_sequence": sequence, "first_timestamp_us": timestamp_us })
                )?;
            } else {
                outln!("{name} = {value} from frame {sequence} (timestamp {timestamp_us} us)")?;
            }
        }
        OnlineCommand::DarkFrame { frames } => {
            let d = with_progress(
                &cam,
                frames,
                "dark frame",
                json,
                cam.capture_dark_frame(frames),
            )
            .await?;
            print_dict(&wire_dict(&d)?, json)?;
        }
        OnlineCommand::Calibrate { frames } => {
            // Dark frames, then 5 photon-transfer levels of frames + 1 each.
            let total = frames.saturating_mul(6).saturating_add(5);
            let d = with_progress(&cam, total, "calibrating", json, cam.calibrate(frames)).await?;
            print_dict(&wire_dict(&d)?, json)?;
        }
        OnlineCommand::Record {
            path,
            seconds,
            by_path,
        } => {
            let path = absolute(&path)?;
            if let Some(s) = seconds {
                if !(s.is_finite() && s > 0.0 && s <= 86_400.0) {
                    return Err(OnlineError::Invalid(format!(
                        "--seconds {s} is out of range: allowed (0, 86400]"
                    )));
                }
            }
            if by_path {
                cam.start_recording(&path).await?;
            } else {
                start_recording_to_fd(&cam, &path).await?;
            }
            match seconds {
                None => {
                    if json {
                        outln!("{}", json!({"recording": path}))?;
                    } else {
                        outln!("recording to {path}; stop with `sdictl stop`")?;
                    }
                }
                Some(s) => {
                    let pb = bar((s * 10.0) as u64, "recording", json);
                    let start = Instant::now();
                    while start.elapsed().as_secs_f64() < s {
                        tokio::time::sleep(Duration::from_millis(100)).await;
                        pb.set_position((start.elapsed().as_secs_f64() * 10.0) as u64);
                    }
                    pb.finish_and_clear();
                    let d = cam.stop_recording().await?;
                    print_dict(&wire_dict(&d)?, json)?;
                }
            }
        }
        OnlineCommand::Stop => {
            let d = cam.stop_recording().await?;
            print_dict(&wire_dict(&d)?, json)?;
        }
        OnlineCommand::Snapshot { path, by_path } => {
            let path = absolute(&path)?;
            if by_path {
                cam.snapshot(&path).await?;
            } else {
                let format = output_extension(&path, &["png", "npy"])?;
                let out = NewFile::create(Path::new(&path))?;
                cam.snapshot_to_fd(Fd::from(out.file()), &format).await?;
                out.commit()?;
            }
            if json {
                outln!("{}", json!({"snapshot": path}))?;
            } else {
                outln!("{path}")?;
            }
        }
        OnlineCommand::Monitor { count } => {
            let mut stream = cam.receive_stats_changed().await;
            let mut n = 0u64;
            if !json {
                outln!(
                    "{:>10} {:>8} {:>12} {:>12} {:>8}",
                    "frames",
                    "fps",
                    "latency_us",
                    "max_us",
                    "dropped"
                )?;
            }
            while let Some(change) = stream.next().await {
                let s = change.get().await?;
                if json {
                    outln!("{}", dict_json(&wire_dict(&s)?))?;
                } else {
                    outln!(
                        "{:>10} {:>8.2} {:>12.0} {:>12.0} {:>8}",
                        s.frames,
                        s.fps,
                        s.latency_us,
                        s.latency_max_us,
                        s.dropped_view + s.dropped_recording
                    )?;
                }
                n += 1;
                if count.is_some_and(|c| n >= c) {
                    break;
                }
            }
        }
        OnlineCommand::Export { .. } => unreachable!("handled offline"),
        OnlineCommand::Doctor { .. } => unreachable!("handled by doctor::run"),
    }
    Ok(())
}
