//! The page's requests to sdid: status, settings, snapshot, recording and
//! calibration, each one D-Bus call through the proxy with the user's
//! rights; sdid's typed errors come back as JSON for the page to show in
//! place (`{"error": kind, "message": ...}`). Every string from the page
//! that goes on to the bus is checked to be a D-Bus string first
//! ([`bus_text`]): the bus drops the connection of a client that sends
//! another.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use sdi_api::{Camera1Proxy, Properties, Setting, SettingKind};
use sdi_core::display::{Colormap, MAX_RANGE_DN};
use sdi_core::mode::ModeId;
use serde::Deserialize;
use serde_json::{json, Map, Value as Json_};
use tokio::sync::Mutex;
use zbus::zvariant::Fd;

use super::bus::Link;
use crate::exit::{CliError, Outcome};
use crate::online::new_file::NewFile;
use crate::online::wire_json;

/// What the handlers share.
pub struct Controls {
    pub bus: Link<Camera1Proxy<'static>>,
    /// The serial of the camera the page shows, for a new connection.
    pub camera: Arc<std::sync::Mutex<Option<String>>>,
    /// The frame stream of the camera the page chose, for the frame pump,
    /// which answers once it reads from it (and shows no frame of the
    /// camera before).
    pub next_stream: tokio::sync::mpsc::Sender<super::frames::Switch>,
    /// Where snapshots and recordings go.
    pub out_dir: PathBuf,
    /// The recording this page started, for its growing size.
    pub recording: Mutex<Option<PathBuf>>,
}

/// A failed call as the page shows it.
pub struct PageError(CliError);

impl<E: Into<CliError>> From<E> for PageError {
    fn from(e: E) -> Self {
        Self(e.into())
    }
}

impl IntoResponse for PageError {
    fn into_response(self) -> Response {
        let outcome = self.0.outcome();
        let status = match outcome {
            Outcome::Invalid => StatusCode::BAD_REQUEST,
            Outcome::Busy | Outcome::NothingToDo => StatusCode::CONFLICT,
            _ => StatusCode::INTERNAL_SERVER_ERROR,
        };
        let body = json!({"error": outcome.kind(), "message": self.0.to_string()});
        (status, Json(body)).into_response()
    }
}

pub(super) type Reply = Result<Json<Json_>, PageError>;

/// Every property (Stats with every key it has), each mode's physical setup
/// (`ModeId::spec`, the table `sdictl status` reads through sdid), the
/// settings the page builds its controls from (`settings`, and the mode's
/// name and property for its buttons), the valid ranges of the controls
/// (`ranges`), and the recording's size.
pub async fn status(State(c): State<Arc<Controls>>) -> Reply {
    let props = c
        .bus
        .call(|cam| async move { Ok(Properties::read(&cam).await?) })
        .await?;
    let modes: Vec<Json_> = ModeId::NAMES
        .iter()
        .filter_map(|n| ModeId::from_name(n).ok())
        .map(|m| {
            let s = m.setup();
            json!({"name": m.name(), "ls1": s.ls1, "ls2": s.ls2, "optics": s.optics})
        })
        .collect();
    let recording = c.recording.lock().await.clone();
    let recording_bytes = match &recording {
        Some(p) => tokio::fs::metadata(p).await.map(|m| m.len()).ok(),
        None => None,
    };
    Ok(Json(json!({
        "properties": wire_json::object(&props)?,
        "modes": modes,
        "mode_setting": {
            "name": Setting::Mode.to_string(),
            "property": Setting::Mode.property_name(),
        },
        "settings": settings(),
        "ranges": ranges(&props.limits),
        "recording_path": recording,
        "recording_bytes": recording_bytes,
    })))
}

/// The page's settings controls, built from [`Setting`]'s table in its
/// order, every setting but the mode (the page's mode buttons, from
/// "modes"): its name (the control's id and the name `/api/set` takes), its
/// D-Bus property, its label, its kind ("number" or "choice") and a
/// choice's names. The page names no setting itself.
fn settings() -> Vec<Json_> {
    Setting::all()
        .filter(|&s| s != Setting::Mode)
        .map(|s| {
            let mut control = Map::new();
            control.insert("name".into(), json!(s.to_string()));
            control.insert("property".into(), json!(s.property_name()));
            control.insert("label".into(), json!(s.label()));
            match s.kind() {
                SettingKind::Number => {
                    control.insert("kind".into(), json!("number"));
                }
                SettingKind::Name => {
                    control.insert("kind".into(), json!("choice"));
                    control.insert("choices".into(), json!(choices(s)));
                }
            }
            Json_::Object(control)
        })
        .collect()
}

/// The names a setting takes, from `sdi_core`'s tables (sdid checks them);
/// none for a number.
fn choices(s: Setting) -> &'static [&'static str] {
    match s {
        Setting::Mode => ModeId::NAMES,
        Setting::Colormap => Colormap::NAMES,
        Setting::ExposureUs | Setting::FrameRate | Setting::ModulationHz | Setting::Range => &[],
    }
}

/// The numeric controls' valid ranges, `[min, max]` by setting name (the
/// page's input ids), every number setting of [`Setting`]'s table: the
/// capture settings' from sdid's `Limits`, the backend's own (a board's
/// narrower than the simulator's), null for one sdid does not name; the
/// display range's from `sdi_core`, as sdid reports no limit for it.
fn ranges(limits: &HashMap<String, (f64, f64)>) -> Map<String, Json_> {
    Setting::all()
        .filter(|s| s.kind() == SettingKind::Number)
        .map(|s| {
            let range = match s {
                Setting::Range => json!([0.0, MAX_RANGE_DN]),
                _ => limits
                    .get(s.property_name())
                    .map_or(Json_::Null, |(min, max)| json!([min, max])),
            };
            (s.to_string(), range)
        })
        .collect()
}

#[derive(Deserialize)]
pub struct SetRequest {
    setting: String,
    value: String,
}

/// `text` if it is a D-Bus string: UTF-8 (a `str` is) without NUL.
pub(super) fn bus_text<'a>(what: &str, text: &'a str) -> Result<&'a str, CliError> {
    if text.contains('\0') {
        return Err(CliError::Usage(format!(
            "{what} contains a NUL character, which D-Bus strings cannot carry"
        )));
    }
    Ok(text)
}

/// Changes one setting; replies with the first frame under it.
pub async fn set(State(c): State<Arc<Controls>>, Json(r): Json<SetRequest>) -> Reply {
    let change = Setting::from_user(&r.setting)?.change(bus_text("the value", &r.value)?)?;
    let (sequence, timestamp_us) = c
        .bus
        .call(|cam| async move { Ok(change.send(&cam).await?) })
        .await?;
    Ok(Json(
        json!({"sequence": sequence, "timestamp_us": timestamp_us}),
    ))
}

#[derive(Deserialize)]
pub struct SnapshotRequest {
    format: String,
}

/// Saves the latest frame as a new `sdi-snapshot-N.png|npy` in the output
/// directory, created by sdictl and written by sdid through the descriptor;
/// N is the first number free when the finished file is linked into place,
/// so snapshots at the same time each get their own.
pub async fn snapshot(State(c): State<Arc<Controls>>, Json(r): Json<SnapshotRequest>) -> Reply {
    let ext = match r.format.as_str() {
        "png" | "npy" => r.format.as_str(),
        other => {
            return Err(CliError::Usage(format!(
                "unknown snapshot format '{other}': allowed png, npy"
            ))
            .into())
        }
    };
    let out = NewFile::numbered(&c.out_dir, "sdi-snapshot", ext)?;
    let fd = Fd::from(out.file());
    c.bus
        .call(|cam| async move { Ok(cam.snapshot_to_fd(fd, ext).await?) })
        .await?;
    let path = out.commit()?;
    Ok(Json(json!({"path": path})))
}

#[derive(Deserialize)]
pub struct RecordRequest {
    start: bool,
}

/// Starts a recording into a new `sdi-recording-N.sdirec`, or stops it.
/// (One at a time: the lock on `recording` is held throughout.)
pub async fn record(State(c): State<Arc<Controls>>, Json(r): Json<RecordRequest>) -> Reply {
    let mut recording = c.recording.lock().await;
    if !r.start {
        let reply = c
            .bus
            .call(|cam| async move { Ok(cam.stop_recording().await?) })
            .await?;
        *recording = None;
        return Ok(Json(Json_::Object(wire_json::object(&reply)?)));
    }
    let path = free_name(&c.out_dir, "sdi-recording", "sdirec");
    // The output directory comes from sdictl's command line: no NUL.
    let label = path.display().to_string();
    let label = bus_text("the path", &label)?;
    let out = NewFile::create(&path)?;
    let fd = Fd::from(out.file());
    c.bus
        .call(|cam| async move { Ok(cam.start_recording_to_fd(fd, label).await?) })
        .await?;
    if let Err(e) = out.commit() {
        let _ = c
            .bus
            .call(|cam| async move { Ok(cam.stop_recording().await?) })
            .await;
        return Err(e.into());
    }
    *recording = Some(path.clone());
    Ok(Json(json!({"path": path})))
}

#[derive(Deserialize)]
pub struct CalibrateRequest {
    frames: u32,
}

/// Runs sdid's calibration (dark frame, then photon transfer); the page
/// shows its progress (sdid's `Job`, in `/api/status`) while this call runs.
pub async fn calibrate(State(c): State<Arc<Controls>>, Json(r): Json<CalibrateRequest>) -> Reply {
    let reply = c
        .bus
        .call(|cam| async move { Ok(cam.calibrate(r.frames).await?) })
        .await?;
    Ok(Json(Json_::Object(wire_json::object(&reply)?)))
}

/// `dir/stem-N.ext` for the first N naming no file (NewFile refuses to
/// replace one that appears in between; one recording at a time).
fn free_name(dir: &std::path::Path, stem: &str, ext: &str) -> PathBuf {
    (1u32..)
        .map(|n| dir.join(format!("{stem}-{n}.{ext}")))
        .find(|p| p.symlink_metadata().is_err())
        .unwrap_or_else(|| dir.join(format!("{stem}.{ext}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_are_sdids_limits_by_the_pages_input_ids() {
        let limits = HashMap::from([
            ("ExposureUs".to_owned(), (1.0, 5461.0)),
            ("FrameRate".to_owned(), (2.861, 31.25)),
        ]);
        let r = ranges(&limits);
        assert_eq!(r["exposure-us"], json!([1.0, 5461.0]));
        assert_eq!(r["frame-rate"], json!([2.861, 31.25]));
        assert_eq!(r["modulation-hz"], Json_::Null);
        assert_eq!(r["range"], json!([0.0, MAX_RANGE_DN]));
    }

    /// (a) Every setting but the mode is one control, once, with its
    /// property, a label and a kind; a choice lists names.
    #[test]
    fn every_setting_but_the_mode_is_one_control() {
        let controls = settings();
        for s in Setting::all() {
            let name = s.to_string();
            let found: Vec<&Json_> = controls.iter().filter(|c| c["name"] == name).collect();
            if s == Setting::Mode {
                assert!(found.is_empty(), "the mode is its buttons: {found:?}");
                continue;
            }
            assert_eq!(found.len(), 1, "{name} in {controls:?}");
            let c = found[0];
            assert_eq!(c["property"], s.property_name(), "{c}");
            assert!(c["label"].as_str().is_some_and(|l| !l.is_empty()), "{c}");
            match s.kind() {
                SettingKind::Number => assert_eq!(c["kind"], "number", "{c}"),
                SettingKind::Name => {
                    assert_eq!(c["kind"], "choice", "{c}");
                    let n = c["choices"].as_array().map_or(0, Vec::len);
                    assert!(n > 0, "{c}");
                }
            }
        }
        assert_eq!(controls.len(), Setting::all().count() - 1, "{controls:?}");
    }

    /// (b) The page names no setting and no property: it builds its
    /// controls from `settings`, so nobody adds a list of its own.
    #[test]
    fn the_page_names_no_setting() {
        let page = [
            ("index.html", include_str!("assets/index.html")),
            ("app.js", include_str!("assets/app.js")),
        ];
        for s in Setting::all() {
            let name = s.to_string();
            let property = s.property_name();
            for (file, text) in page {
                for q in ['"', '\'', '`'] {
                    for literal in [format!("{q}{name}{q}"), format!("{q}{property}{q}")] {
                        assert!(!text.contains(&literal), "{file} names {literal}");
                    }
                }
                let member = format!(".{property}");
                assert!(!text.contains(&member), "{file} reads {member}");
            }
        }
    }

    /// (c) The colormap's choices are `sdi_core`'s colormaps, each by the
    /// name it parses from and shows as.
    #[test]
    fn the_colormap_choices_are_sdi_cores() {
        let controls = settings();
        let colormap = Setting::Colormap.to_string();
        let c = controls.iter().find(|c| c["name"] == colormap);
        let choices = c.map(|c| c["choices"].clone());
        assert_eq!(choices, Some(json!(Colormap::NAMES)), "{controls:?}");
        for name in Colormap::NAMES {
            let parsed = name.parse::<Colormap>().map(Colormap::name);
            assert_eq!(parsed, Ok(*name));
        }
    }

    #[test]
    fn a_nul_is_no_bus_text() {
        assert_eq!(bus_text("v", "raw").unwrap(), "raw");
        let e = bus_text("the value", "raw\0").unwrap_err();
        assert!(matches!(e, CliError::Usage(_)), "{e}");
        assert!(e.to_string().contains("NUL"), "{e}");
    }
}
