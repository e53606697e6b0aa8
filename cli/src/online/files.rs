//! `sdictl record`, `stop` and `snapshot`: output files created by sdictl as
//! the calling user and handed to sdid as descriptors, or (`--by-path`)
//! created by sdid in its state directory.

use std::path::Path;
use std::time::{Duration, Instant};

use sdi_api::Camera1Proxy;
use serde_json::json;
use zbus::zvariant::Fd;

use super::long_call::bar;
use super::new_file::NewFile;
use super::wire_json;
use crate::exit::CliError;
use crate::stdout::outln;

/// Longest `record --seconds` takes, a day.
const MAX_RECORD_SECONDS: f64 = 86_400.0;

pub async fn record(
    camera: &Camera1Proxy<'_>,
    path: &Path,
    seconds: Option<f64>,
    by_path: bool,
    json: bool,
) -> Result<(), CliError> {
    let path = absolute(path)?;
    if let Some(s) = seconds {
        if !(s.is_finite() && s > 0.0 && s <= MAX_RECORD_SECONDS) {
            return Err(CliError::Usage(format!(
                "--seconds {s} is out of range: allowed (0, 86400]"
            )));
        }
    }
    if by_path {
        camera.start_recording(&path).await?;
    } else {
        start_recording_to_fd(camera, &path).await?;
    }
    let Some(s) = seconds else {
        if json {
            outln!("{}", json!({"recording": path}))?;
        } else {
            outln!("recording to {path}; stop with `sdictl stop`")?;
        }
        return Ok(());
    };
    let pb = bar((s * 10.0) as u64, "recording", json);
    let start = Instant::now();
    while start.elapsed().as_secs_f64() < s {
        tokio::time::sleep(Duration::from_millis(100)).await;
        pb.set_position((start.elapsed().as_secs_f64() * 10.0) as u64);
    }
    pb.finish_and_clear();
    stop(camera, json).await
}

pub async fn stop(camera: &Camera1Proxy<'_>, json: bool) -> Result<(), CliError> {
    let reply = camera.stop_recording().await?;
    wire_json::print(&reply, json)
}

pub async fn snapshot(
    camera: &Camera1Proxy<'_>,
    path: &Path,
    by_path: bool,
    json: bool,
) -> Result<(), CliError> {
    let path = absolute(path)?;
    if by_path {
        camera.snapshot(&path).await?;
    } else {
        let format = output_extension(&path, &["png", "npy"])?;
        let out = NewFile::create(Path::new(&path))?;
        camera.snapshot_to_fd(Fd::from(out.file()), &format).await?;
        out.commit()?;
    }
    if json {
        outln!("{}", json!({"snapshot": path}))?;
    } else {
        outln!("{path}")?;
    }
    Ok(())
}

/// Creates the recording as the calling user and starts the daemon writing
/// into its descriptor; the file gets its name once the daemon has accepted
/// it (the header is written by then, and the format survives a crash).
async fn start_recording_to_fd(camera: &Camera1Proxy<'_>, path: &str) -> Result<(), CliError> {
    output_extension(path, &["sdirec"])?;
    let out = NewFile::create(Path::new(path))?;
    camera
        .start_recording_to_fd(Fd::from(out.file()), path)
        .await?;
    if let Err(e) = out.commit() {
        // Nothing may record into a file that has no name.
        let _ = camera.stop_recording().await;
        return Err(e);
    }
    Ok(())
}

/// `path` made absolute against the working directory, as text (sdid's
/// labels and path methods take strings).
fn absolute(path: &Path) -> Result<String, CliError> {
    let p = if path.is_absolute() {
        path.to_owned()
    } else {
        std::env::current_dir()
            .map_err(|e| CliError::Runtime(e.to_string()))?
            .join(path)
    };
    p.to_str()
        .map(str::to_owned)
        .ok_or_else(|| CliError::Usage(format!("{} is not valid UTF-8", p.display())))
}

/// The lower-case extension of `path` if it is one of `allowed`.
fn output_extension(path: &str, allowed: &[&str]) -> Result<String, CliError> {
    let ext = Path::new(path)
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if allowed.contains(&ext.as_str()) {
        Ok(ext)
    } else {
        Err(CliError::Usage(format!(
            "{path}: the extension must be one of .{}",
            allowed.join(", .")
        )))
    }
}
