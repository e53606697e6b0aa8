//! Snapshots: the latest processed frame written as PNG or NPY into a file
//! in the state directory or a caller's descriptor.

use std::time::Duration;

use zbus::message::Header;
use zbus::Connection;

use super::caller::caller_uid;
use super::Camera;
use crate::dbus::client_fd;
use crate::dbus::errors::SdiError;
use crate::dbus::paths::OutputKind;
use crate::frame_loop::Command;

impl Camera {
    /// Writes the latest frame to a new file `STATE_DIR/NAME.png` or `NAME.npy`.
    pub(super) async fn snapshot_to_state_dir(
        &self,
        path: &str,
        hdr: &Header<'_>,
        conn: &Connection,
    ) -> Result<(), SdiError> {
        let uid = caller_uid(conn, hdr).await;
        let out = self.create_in_state_dir(path, &[OutputKind::Png, OutputKind::Npy], uid)?;
        let written = match (out.file.try_clone(), self.latest_frame().await) {
            (Ok(file), Ok(snap)) => {
                let kind = out.kind;
                tokio::task::spawn_blocking(move || crate::snapshot::write_to(file, kind, &snap))
                    .await
                    .map_err(|e| SdiError::Failed(e.to_string()))
                    .and_then(|r| {
                        r.map_err(|e| SdiError::Failed(format!("{}: {e}", out.path.display())))
                    })
            }
            (Err(e), _) => Err(SdiError::Failed(format!("duplicating a descriptor: {e}"))),
            (_, Err(e)) => Err(e),
        };
        if written.is_err() {
            out.discard();
        }
        written
    }

    /// Writes the latest frame into `fd` as `format` ("png" or "npy").
    pub(super) async fn snapshot_into_fd(
        &self,
        fd: zbus::zvariant::OwnedFd,
        format: &str,
    ) -> Result<(), SdiError> {
        let kind = client_fd::snapshot_format(format)?;
        let file = client_fd::output_file(fd.into())?;
        let snap = self.latest_frame().await?;
        tokio::task::spawn_blocking(move || crate::snapshot::write_to(file, kind, &snap))
            .await
            .map_err(|e| SdiError::Failed(e.to_string()))?
            .map_err(|e| SdiError::Failed(format!("writing the snapshot: {e}")))
    }

    /// The latest processed frame, waiting up to 2 s for the first one.
    async fn latest_frame(&self) -> Result<crate::frame_loop::SnapshotData, SdiError> {
        self.require_device()?;
        // The job takes the frames until it ends: answer now, not then.
        if let Some(busy) = self
            .jobs
            .busy("a snapshot is refused (the frames go to the job)")
        {
            return Err(busy);
        }
        for _ in 0..20 {
            if let Some(snap) = self.ask(Command::Snapshot).await? {
                return Ok(snap);
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        Err(SdiError::NoFrame("no frame has been processed yet".into()))
    }
}
