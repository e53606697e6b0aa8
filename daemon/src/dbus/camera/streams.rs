//! Frame streams: every mode output written into a caller's pipe or socket
//! until the caller closes it or leaves the bus.

use zbus::message::Header;
use zbus::Connection;

use super::Camera;
use crate::dbus::client_fd;
use crate::dbus::errors::SdiError;
use crate::dbus::peers;
use crate::frame_loop::Command;

impl Camera {
    /// Hands `fd` to the frame loop as a stream owned by the caller.
    pub(super) async fn open_stream(
        &self,
        fd: zbus::zvariant::OwnedFd,
        hdr: &Header<'_>,
        conn: &Connection,
    ) -> Result<(), SdiError> {
        use crate::frame_stream::StreamError;
        let target = client_fd::stream_target(fd.into())?;
        let caller = peers::caller(hdr)
            .ok_or_else(|| SdiError::Failed("the call names no sender".into()))?;
        let owner = caller.to_string();
        self.ask(|reply| Command::StreamFrames(target, owner.clone(), reply))
            .await?
            .map_err(|e| match e {
                StreamError::TooMany | StreamError::TooManyForPeer => SdiError::Busy(e.to_string()),
                StreamError::Thread(_) => SdiError::Failed(e.to_string()),
            })?;
        // The stream is the caller's: it ends when the caller leaves the
        // bus. One watch per connection, however many streams it opens.
        let commands = self.commands.lock().map(|tx| tx.clone());
        if let (Ok(commands), true) = (commands, self.stream_owners.insert(&owner)) {
            let conn = conn.clone();
            let owners = self.stream_owners.clone();
            tokio::spawn(async move {
                peers::left_bus(conn, caller).await;
                owners.remove(&owner);
                let _ = commands.send(Command::PeerLeft(owner));
            });
        }
        Ok(())
    }
}
