//! `sdictl dark-frame`, `calibrate` and `calibrate phase`: calls that take
//! many frames, shown with a progress bar that follows sdid's `Job`
//! property. Ctrl-C cancels the job (`Cancel`) and waits for sdid to end
//! it; a second Ctrl-C leaves at once (sdid then ends the job because its
//! caller left the bus).

use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use sdi_api::{Camera1Proxy, SdiError};
use tokio::signal::unix::{signal, SignalKind};

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

/// Runs a long call while a progress bar shows sdid's count of its frames.
async fn with_progress<T>(
    camera: &Camera1Proxy<'_>,
    frames: u32,
    msg: &str,
    json: bool,
    call: impl std::future::Future<Output = Result<T, SdiError>>,
) -> Result<T, CliError> {
    let pb = bar(frames as u64, msg, json);
    let mut interrupt =
        signal(SignalKind::interrupt()).map_err(|e| CliError::Runtime(e.to_string()))?;
    let mut cancelling = false;
    tokio::pin!(call);
    let mut tick = tokio::time::interval(Duration::from_millis(200));
    let r = loop {
        tokio::select! {
            r = &mut call => break r,
            _ = tick.tick() => {
                if let Ok(job) = camera.job().await {
                    if job.frames_total > 0 {
                        pb.set_length(u64::from(job.frames_total));
                        pb.set_position(u64::from(job.frames_done));
                    }
                }
            }
            _ = interrupt.recv() => {
                if cancelling {
                    pb.finish_and_clear();
                    return Err(CliError::Runtime("interrupted".into()));
                }
                cancelling = true;
                pb.set_message(format!("{msg}: cancelling"));
                // A refusal (another user's job) leaves the call running.
                if let Err(e) = camera.cancel().await {
                    pb.println(format!("cancel: {e}"));
                }
            }
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
    // Dark frames, then 5 photon-transfer levels (sdid's Job says).
    let total = frames.saturating_mul(6);
    let call = camera.calibrate(frames);
    let reply = with_progress(camera, total, "calibrating", json, call).await?;
    wire_json::print(&reply, json)
}

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
    let call = camera.calibrate_phase(frames);
    let reply = with_progress(camera, frames, "phase", json, call).await?;
    if !json && reply.lights.is_empty() {
        eprintln!("sdid drives no lights: the axis assumes LS2 was covered");
    }
    wire_json::print(&reply, json)
}
