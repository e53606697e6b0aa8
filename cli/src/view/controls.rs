//! The page's requests to sdid: status, settings, snapshot, recording and
//! calibration, each one D-Bus call through the proxy with the user's
//! rights; sdid's typed errors come back as JSON for the page to show in
//! place (`{"error": kind, "message": ...}`).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use sdi_api::{Camera1Proxy, Properties, Setting};
use sdi_core::display::MAX_RANGE_DN;
use sdi_core::mode::ModeId;
use serde::Deserialize;
use serde_json::{json, Map, Value as Json_};
use tokio::sync::Mutex;
use zbus::zvariant::Fd;

use crate::exit::{CliError, Outcome};
use crate::online::new_file::NewFile;
use crate::online::wire_json;

/// What the handlers share.
pub struct Controls {
    pub camera: Camera1Proxy<'static>,
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

type Reply = Result<Json<Json_>, PageError>;

/// Every property (Stats with every key it has), each mode's physical setup
/// (`ModeId::spec`, the table `sdictl status` reads through sdid), the
/// valid ranges of the controls (`ranges`), and the recording's size.
pub async fn status(State(c): State<Arc<Controls>>) -> Reply {
    let props = Properties::read(&c.camera).await?;
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
        "ranges": ranges(&props.limits),
        "recording_path": recording,
        "recording_bytes": recording_bytes,
    })))
}

/// The numeric controls' valid ranges, `[min, max]` by setting name (the
/// page's input ids): the capture settings' from sdid's `Limits`, the
/// backend's own (a board's narrower than the simulator's), null for one
/// sdid does not name; the display range's from `sdi_core`, as sdid
/// reports no limit for it.
fn ranges(limits: &HashMap<String, (f64, f64)>) -> Map<String, Json_> {
    let mut out: Map<String, Json_> = [
        Setting::ExposureUs,
        Setting::FrameRate,
        Setting::ModulationHz,
    ]
    .into_iter()
    .map(|s| {
        let range = limits
            .get(s.property_name())
            .map_or(Json_::Null, |(min, max)| json!([min, max]));
        (s.to_string(), range)
    })
    .collect();
    out.insert(Setting::Range.to_string(), json!([0.0, MAX_RANGE_DN]));
    out
}

#[derive(Deserialize)]
pub struct SetRequest {
    setting: String,
    value: String,
}

/// Changes one setting; replies with the first frame under it.
pub async fn set(State(c): State<Arc<Controls>>, Json(r): Json<SetRequest>) -> Reply {
    let change = Setting::from_user(&r.setting)?.change(&r.value)?;
    let (sequence, timestamp_us) = change.send(&c.camera).await?;
    Ok(Json(
        json!({"sequence": sequence, "timestamp_us": timestamp_us}),
    ))
}

#[derive(Deserialize)]
pub struct SnapshotRequest {
    format: String,
}

/// Saves the latest frame as a new `sdi-snapshot-N.png|npy` in the output
/// directory, created by sdictl and written by sdid through the descriptor.
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
    let path = free_name(&c.out_dir, "sdi-snapshot", ext);
    let out = NewFile::create(&path)?;
    c.camera.snapshot_to_fd(Fd::from(out.file()), ext).await?;
    out.commit()?;
    Ok(Json(json!({"path": path})))
}

#[derive(Deserialize)]
pub struct RecordRequest {
    start: bool,
}

/// Starts a recording into a new `sdi-recording-N.sdirec`, or stops it.
pub async fn record(State(c): State<Arc<Controls>>, Json(r): Json<RecordRequest>) -> Reply {
    let mut recording = c.recording.lock().await;
    if !r.start {
        let reply = c.camera.stop_recording().await?;
        *recording = None;
        return Ok(Json(Json_::Object(wire_json::object(&reply)?)));
    }
    let path = free_name(&c.out_dir, "sdi-recording", "sdirec");
    let label = path.display().to_string();
    let out = NewFile::create(&path)?;
    c.camera
        .start_recording_to_fd(Fd::from(out.file()), &label)
        .await?;
    if let Err(e) = out.commit() {
        let _ = c.camera.stop_recording().await;
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
    let reply = c.camera.calibrate(r.frames).await?;
    Ok(Json(Json_::Object(wire_json::object(&reply)?)))
}

/// `dir/stem-N.ext` for the first N naming no file (NewFile refuses to
/// replace one that appears in between).
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
}
