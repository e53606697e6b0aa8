//! `sdictl dark-frame`, `calibrate` and `calibrate phase`: calls that take
//! many frames, shown with a progress bar that advances at the camera's
//! frame rate.

use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use sdi_api::{Camera1Proxy, SdiError};

use super::wire_json;
use crate::exit::CliError;

/// A progress bar of `len` steps; hidden under `--json`.
pub fn bar(len: u64, msg: &str, json: bool) -> ProgressBar {
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
    camera: &Camera1Proxy<'_>,
    frames: u32,
    msg: &str,
    json: bool,
    call: impl std::future::Future<Output = Result<T, SdiError>>,
) -> Result<T, CliError> {
    let fps = camera.frame_rate().await.unwrap_or(30.0).max(0.1);
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

pub async fn dark_frame(
    camera: &Camera1Proxy<'_>,
    frames: u32,
    json: bool,
) -> Result<(), CliError> {
    let call = camera.capture_dark_frame(frames);
    let reply = with_progress(camera, frames, "dark frame", json, call).await?;
    wire_json::print(&reply, json)
}

pub async fn calibrate(camera: &Camera1Proxy<'_>, frames: u32, json: bool) -> Result<(), CliError> {
    // Dark frames, then 5 photon-transfer levels of frames + 1 each.
    let total = frames.saturating_mul(6).saturating_add(5);
    let call = camera.calibrate(frames);
    let reply = with_progress(camera, total, "calibrating", json, call).await?;
    wire_json::print(&reply, json)
}

/// Frames the phase calibration leaves out while the light settles
/// (sdid's `phase_calibration::FRAMES_IN_FLIGHT` and one to settle).
const PHASE_SETTLE_FRAMES: u32 = 6;

pub async fn calibrate_phase(
    camera: &Camera1Proxy<'_>,
    frames: u32,
    json: bool,
) -> Result<(), CliError> {
    if !json {
        eprintln!(
            "phase calibration: LS1 alone must light the scene (sdid switches LS2 off \
             through [lights]; without a light rig, cover LS2 now)"
        );
    }
    let total = frames.saturating_add(PHASE_SETTLE_FRAMES);
    let call = camera.calibrate_phase(frames);
    let reply = with_progress(camera, total, "phase", json, call).await?;
    if !json && reply.lights.is_empty() {
        eprintln!("sdid drives no lights: the axis assumes LS2 was covered");
    }
    wire_json::print(&reply, json)
}
