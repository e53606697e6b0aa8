//! Who calls: the caller's user id, and the files path methods create for it.

use zbus::message::Header;
use zbus::Connection;

use super::Camera;
use crate::dbus::client_file;
use crate::dbus::errors::SdiError;
use crate::dbus::paths::OutputKind;

/// The caller's Unix user id, as the bus reports it; None when unknown.
pub(super) async fn caller_uid(conn: &Connection, hdr: &Header<'_>) -> Option<u32> {
    let sender = hdr.sender()?.to_owned();
    let proxy = zbus::fdo::DBusProxy::new(conn).await.ok()?;
    proxy
        .get_connection_unix_user(zbus::names::BusName::Unique(sender))
        .await
        .ok()
}

impl Camera {
    /// Creates `path` for a path method: a new file directly in the state
    /// directory, owned by the caller (`client_file`).
    pub(super) fn create_in_state_dir(
        &self,
        path: &str,
        allowed: &[OutputKind],
        uid: Option<u32>,
    ) -> Result<client_file::StateDirFile, SdiError> {
        client_file::create(self.info.state_dir.as_deref(), path, allowed, uid)
    }
}
