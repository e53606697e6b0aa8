//! Stopping in order: the stop's reason (a signal, or a board unplugged
//! with `on_unplug = "exit"`), the name released, each camera's frame loop
//! stopped and its recording finished, each within its timeout.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Notify;

use super::camera::{FrameLoopHandle, Running};
use super::StartError;
use crate::dbus::camera::Camera;
use crate::dbus::BUS_NAME;
use crate::frame_loop::Command;
use crate::recorder::RecordingWriter;

/// Shutdown stays within the unit's TimeoutStopSec (15 s) whatever hangs:
/// releasing the bus name, the frame loop (a source stuck in a read), the
/// recorder (frozen storage). What does not finish in time is abandoned,
/// and the log says what.
const NAME_RELEASE_TIMEOUT: Duration = Duration::from_secs(2);

const FRAME_LOOP_STOP_TIMEOUT: Duration = Duration::from_secs(5);

const RECORDING_FINISH_TIMEOUT: Duration = Duration::from_secs(5);

/// Waits for `stop` or, with `on_unplug = "exit"`, a board's unplugging
/// (`exits`, told by any camera's board); the reason, for the log.
pub(super) async fn wait_for_stop(
    stop: impl std::future::Future<Output = &'static str>,
    exits: &Arc<Notify>,
) -> &'static str {
    tokio::select! {
        why = stop => why,
        _ = exits.notified() => "board unplugged and [board] on_unplug = \"exit\"",
    }
}

/// Releases the name, then stops each camera's frame loop and finishes
/// its running recording, each within its timeout.
pub(super) async fn shut_down(
    conn: &zbus::Connection,
    running: Vec<Running>,
) -> Result<(), StartError> {
    let mut recordings = Vec::new();
    for r in &running {
        recordings.push(recording_label(conn, &r.path).await);
    }
    if tokio::time::timeout(NAME_RELEASE_TIMEOUT, conn.release_name(BUS_NAME))
        .await
        .is_err()
    {
        tracing::warn!("releasing {BUS_NAME} took over {NAME_RELEASE_TIMEOUT:?}; going on");
    }
    // Every loop is told first, so the cameras stop together.
    for r in &running {
        r.stats.abort();
        let _ = r.frames.commands.send(Command::Shutdown);
    }
    for (r, recording) in running.into_iter().zip(recordings) {
        if let Some(recorder) = stop_frame_loop(r.frames, &recording).await? {
            finish_recording(recorder).await;
        }
    }
    Ok(())
}

/// The file being recorded to, "" when none.
async fn recording_label(conn: &zbus::Connection, path: &str) -> String {
    match conn.object_server().interface::<_, Camera>(path).await {
        Ok(iface) => iface
            .get()
            .await
            .recording_path()
            .map(|p| p.display().to_string())
            .unwrap_or_default(),
        Err(_) => String::new(),
    }
}

/// Stops the frame loop; its recorder, if one runs, for the caller to
/// finish. A loop that does not stop in time is abandoned (`None`).
async fn stop_frame_loop(
    frames: FrameLoopHandle,
    recording: &str,
) -> Result<Option<RecordingWriter>, StartError> {
    let _ = frames.commands.send(Command::Shutdown);
    let thread = frames.thread;
    let joined = tokio::time::timeout(
        FRAME_LOOP_STOP_TIMEOUT,
        tokio::task::spawn_blocking(move || thread.join()),
    )
    .await;
    match joined {
        Ok(r) => r
            .map_err(StartError::JoinFrameLoop)?
            .map_err(|_| StartError::FrameLoopPanicked),
        Err(_) => {
            let lost = if recording.is_empty() {
                String::new()
            } else {
                format!(", and the recording {recording:?} without its end record")
            };
            tracing::error!(
                "the frame loop did not stop within {FRAME_LOOP_STOP_TIMEOUT:?} (the source is stuck); abandoning it{lost}"
            );
            Ok(None)
        }
    }
}

/// Finishes the recording within the unit's TimeoutStopSec, even on
/// frozen storage.
async fn finish_recording(recorder: RecordingWriter) {
    let path = recorder.path().display().to_string();
    match tokio::task::spawn_blocking(move || recorder.finish_within(RECORDING_FINISH_TIMEOUT))
        .await
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
