//! Recording raw sensor frames: started into a file in the state directory
//! or a caller's descriptor, stopped by the caller or by the recorder itself.

use std::path::PathBuf;

use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::Connection;

use super::caller::caller_uid;
use super::state::State;
use super::Camera;
use crate::dbus::client_fd::{self, recording_label};
use crate::dbus::errors::SdiError;
use crate::dbus::paths::OutputKind;
use crate::frame_loop::Command;
use crate::recorder::{RecordingWriter, StopCause};
use sdi_api::RecordingReply;
use sdi_config::RecordingSection;
use sdi_recording::Header as RecHeader;

/// Longest a StopRecording call waits for storage to take the rest of the
/// recording (the recorder thread goes on after that).
pub const RECORDING_FINISH_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);

/// Recording steps shared by the path and descriptor methods.
impl Camera {
    /// Starts recording into a new file `STATE_DIR/NAME.sdirec` for the caller.
    pub(super) async fn record_to_state_dir(
        &self,
        path: &str,
        hdr: &Header<'_>,
        conn: &Connection,
        emitter: &SignalEmitter<'_>,
    ) -> Result<(), SdiError> {
        let uid = caller_uid(conn, hdr).await;
        let out = self.create_in_state_dir(path, &[OutputKind::Recording], uid)?;
        let (file, label) = match out.file.try_clone() {
            Ok(f) => (f, out.path.clone()),
            Err(e) => {
                out.discard();
                return Err(SdiError::Failed(format!("duplicating a descriptor: {e}")));
            }
        };
        let l2 = label.clone();
        let started = self
            .begin_recording(label, emitter, move |header, limits| {
                RecordingWriter::from_file(file, &l2, header, limits)
            })
            .await;
        if started.is_err() {
            out.discard();
        }
        started
    }

    /// Starts recording into `fd`, shown as `label`.
    pub(super) async fn record_to_fd(
        &self,
        fd: zbus::zvariant::OwnedFd,
        label: &str,
        emitter: &SignalEmitter<'_>,
    ) -> Result<(), SdiError> {
        let label = PathBuf::from(recording_label(label)?);
        let file = client_fd::output_file(fd.into())?;
        let l2 = label.clone();
        self.begin_recording(label, emitter, move |header, limits| {
            RecordingWriter::from_file(file, &l2, header, limits)
        })
        .await
    }

    /// Stops the recording a client started and waits for its last frames.
    pub(super) async fn end_recording(
        &self,
        emitter: &SignalEmitter<'_>,
    ) -> Result<RecordingReply, SdiError> {
        let _guard = self.change_lock.lock().await;
        let Some(path) = self.state().recording else {
            let mut stopped = None;
            self.update(|s| stopped = s.recording_stopped.take());
            return Err(match stopped {
                Some(why) => SdiError::RecordingStopped(why),
                None => SdiError::NotRecording("no recording in progress".into()),
            });
        };
        let writer = self.ask(Command::StopRecording).await?;
        self.update(|s| s.recording = None);
        let _ = self.recording_changed(emitter).await;
        let writer =
            writer.ok_or_else(|| SdiError::NotRecording("no recording in progress".into()))?;
        // The recorder thread writes the rest; the frame loop goes on meanwhile.
        let summary =
            tokio::task::spawn_blocking(move || writer.finish_within(RECORDING_FINISH_TIMEOUT))
                .await
                .map_err(|e| SdiError::Failed(e.to_string()))?
                .map_err(|e| SdiError::Failed(format!("{}: {e}", path.display())))?;
        tracing::info!(path = ?path, frames = summary.frames, dropped = summary.dropped, "recording stopped");
        Ok(RecordingReply {
            path: path.display().to_string(),
            frames: summary.frames,
            dropped: summary.dropped,
        })
    }

    fn recording_header(&self, st: &State) -> RecHeader {
        let mut sensor = self.info.sensor.clone();
        sensor.exposure_us = st.capture.exposure_us;
        sensor.frame_rate_hz = st.capture.frame_rate_hz;
        sensor.modulation_hz = st.capture.modulation_hz;
        RecHeader {
            format_version: 1,
            mode: st.mode.name().into(),
            backend: self.info.backend.to_string(),
            sensor,
            exposure_us: st.capture.exposure_us,
            frame_rate_hz: st.capture.frame_rate_hz,
            modulation_hz: st.capture.modulation_hz,
            started_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
            calibration: self.calibration.borrow().clone(),
        }
    }

    /// Opens a writer with `open` (off the async runtime) and hands it to the
    /// frame loop; `label` is what the Recording property shows.
    async fn begin_recording(
        &self,
        label: PathBuf,
        emitter: &SignalEmitter<'_>,
        open: impl FnOnce(&RecHeader, RecordingSection) -> std::io::Result<RecordingWriter>
            + Send
            + 'static,
    ) -> Result<(), SdiError> {
        let _guard = self.change_lock.lock().await;
        if let Some(busy) = self
            .jobs
            .busy("a recording is refused (it would have a gap while the job takes the frames)")
        {
            return Err(busy);
        }
        let st = self.state();
        if let Some(p) = &st.recording {
            return Err(SdiError::Busy(format!(
                "already recording to {}",
                p.display()
            )));
        }
        let header = self.recording_header(&st);
        let limits = self.info.recording;
        let mut writer = tokio::task::spawn_blocking(move || open(&header, limits))
            .await
            .map_err(|e| SdiError::Failed(e.to_string()))?
            .map_err(|e| SdiError::InvalidPath(format!("{}: {e}", label.display())))?;
        let ended = writer.take_ended();
        self.ask(|tx| Command::StartRecording(Box::new(writer), tx))
            .await?;
        tracing::info!(path = ?label, "recording started");
        self.update(|s| {
            s.recording = Some(label.clone());
            s.recording_stopped = None;
        });
        let _ = self.recording_changed(emitter).await;
        if let Some(ended) = ended {
            let server = emitter.connection().object_server().clone();
            let path = emitter.path().to_owned();
            tokio::spawn(async move {
                let Ok(cause) = ended.await else { return };
                if let Ok(iface) = server.interface::<_, Camera>(path).await {
                    iface
                        .get()
                        .await
                        .recording_ended(label, cause, iface.signal_emitter())
                        .await;
                }
            });
        }
        Ok(())
    }

    /// The recorder stopped by itself: take it from the frame loop, clear
    /// the Recording property, emit `RecordingStopped` and Stats at once.
    async fn recording_ended(&self, label: PathBuf, cause: StopCause, emitter: &SignalEmitter<'_>) {
        let _guard = self.change_lock.lock().await;
        if self.state().recording.as_ref() != Some(&label) {
            return; // stopped by a client meanwhile
        }
        let frames = match self.ask(Command::StopRecording).await {
            Ok(Some(w)) => {
                tokio::task::spawn_blocking(move || w.finish_within(RECORDING_FINISH_TIMEOUT))
                    .await
                    .ok()
                    .and_then(Result::ok)
                    .map_or(0, |s| s.frames)
            }
            _ => 0,
        };
        let reason = format!(
            "recording {} stopped after {frames} frames: {cause}",
            label.display()
        );
        tracing::error!(path = ?label, frames, "{reason}");
        self.update(|s| {
            s.recording = None;
            s.recording_stopped = Some(reason.clone());
        });
        let _ = self.recording_changed(emitter).await;
        let _ = self.stats_changed(emitter).await;
        let _ =
            Self::recording_stopped(emitter, &label.display().to_string(), &reason, frames).await;
    }
}
