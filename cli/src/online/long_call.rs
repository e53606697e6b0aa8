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
///
/// The call runs in a task of its own: its first poll sends the method
/// call, and a future queued for zbus's write lock must not sit unpolled
/// beside a `select!` body that sends (here the progress tick's `Job`
/// read): the lock, handed out in turn, would go to it, and every send
/// would wait for good (the stall sdid's jobs had; `peers::Departure` in
/// the daemon).
async fn with_progress<T, F, Fut>(
    camera: &Camera1Proxy<'static>,
    frames: u32,
    msg: &str,
    json: bool,
    call: F,
) -> Result<T, CliError>
where
    F: FnOnce(Camera1Proxy<'static>) -> Fut,
    Fut: std::future::Future<Output = Result<T, SdiError>> + Send + 'static,
    T: Send + 'static,
{
    let pb = bar(frames as u64, msg, json);
    let mut interrupt =
        signal(SignalKind::interrupt()).map_err(|e| CliError::Runtime(e.to_string()))?;
    let mut cancelling = false;
    let mut call = tokio::spawn(call(camera.clone()));
    // Leaving early (a second Ctrl-C) drops the call with the task.
    let _abort = AbortOnDrop(call.abort_handle());
    let mut tick = tokio::time::interval(Duration::from_millis(200));
    let r = loop {
        tokio::select! {
            r = &mut call => break r.map_err(|e| CliError::Runtime(format!("the call's task: {e}")))?,
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
    camera: &Camera1Proxy<'static>,
    frames: u32,
    json: bool,
) -> Result<(), CliError> {
    let call = move |c: Camera1Proxy<'static>| async move { c.capture_dark_frame(frames).await };
    let reply = with_progress(camera, frames, "dark frame", json, call).await?;
    wire_json::print(&reply, json)
}

pub async fn calibrate(
    camera: &Camera1Proxy<'static>,
    frames: u32,
    json: bool,
) -> Result<(), CliError> {
    // Dark frames, then 5 photon-transfer levels (sdid's Job says).
    let total = frames.saturating_mul(6);
    let call = move |c: Camera1Proxy<'static>| async move { c.calibrate(frames).await };
    let reply = with_progress(camera, total, "calibrating", json, call).await?;
    wire_json::print(&reply, json)
}

pub async fn calibrate_phase(
    camera: &Camera1Proxy<'static>,
    frames: u32,
    json: bool,
) -> Result<(), CliError> {
    if !json {
        eprintln!(
            "phase calibration: LS1 alone must light the scene (sdid switches LS2 off \
             through [lights]; without a light rig, cover LS2 now)"
        );
    }
    let call = move |c: Camera1Proxy<'static>| async move { c.calibrate_phase(frames).await };
    let reply = with_progress(camera, frames, "phase", json, call).await?;
    if !json && reply.lights.is_empty() {
        eprintln!("sdid drives no lights: the axis assumes LS2 was covered");
    }
    wire_json::print(&reply, json)
}

/// Aborts a task when dropped.
struct AbortOnDrop(tokio::task::AbortHandle);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}
