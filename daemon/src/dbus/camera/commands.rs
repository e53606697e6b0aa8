//! Commands to the frame loop and the answers it sends back.

use tokio::sync::oneshot;

use super::Camera;
use crate::dbus::errors::{frame_loop_stopped, SdiError};
use crate::frame_loop::{Command, FrameMark};

impl Camera {
    pub(super) fn send(&self, cmd: Command) -> Result<(), SdiError> {
        let tx = self
            .commands
            .lock()
            .map_err(|_| SdiError::Failed("command channel poisoned".into()))?;
        tx.send(cmd).map_err(frame_loop_stopped)
    }

    pub(super) async fn ask<T>(
        &self,
        make: impl FnOnce(oneshot::Sender<T>) -> Command,
    ) -> Result<T, SdiError> {
        let (tx, rx) = oneshot::channel();
        self.send(make(tx))?;
        rx.await.map_err(frame_loop_stopped)
    }

    /// Waits for the frame loop's answer to a setting change.
    pub(super) async fn first_frame(
        rx: oneshot::Receiver<FrameMark>,
    ) -> Result<(u64, u64), SdiError> {
        let m = rx.await.map_err(frame_loop_stopped)?;
        Ok((m.sequence, m.timestamp_us))
    }
}
