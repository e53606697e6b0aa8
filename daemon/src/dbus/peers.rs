//! Callers as bus connections: what a call's unique sender name is, and
//! when that connection leaves the bus (its `NameOwnerChanged` with no new
//! owner). What a caller holds beyond its call (a frame stream's slot, a
//! job) is given back then.

use std::collections::HashSet;
use std::sync::{Arc, Mutex};

use futures_util::StreamExt;
use zbus::fdo::DBusProxy;
use zbus::message::Header;
use zbus::names::{BusName, OwnedUniqueName};
use zbus::Connection;

/// The unique name of the connection that sent the call, if the bus says.
pub fn caller(hdr: &Header<'_>) -> Option<OwnedUniqueName> {
    hdr.sender().map(|s| s.to_owned().into())
}

/// Resolves once `name` has left the bus (at once if it already has).
/// Subscribes before asking, so a departure between the two is not missed;
/// a bus that cannot be asked counts as the name gone (the holder frees
/// what it holds rather than keep it forever).
pub async fn left_bus(conn: Connection, name: OwnedUniqueName) {
    let Ok(bus) = DBusProxy::new(&conn).await else {
        return;
    };
    let Ok(mut changes) = bus
        .receive_name_owner_changed_with_args(&[(0, name.as_str())])
        .await
    else {
        return;
    };
    if !bus
        .name_has_owner(BusName::Unique(name.as_ref()))
        .await
        .unwrap_or(false)
    {
        return;
    }
    while let Some(signal) = changes.next().await {
        match signal.args() {
            Ok(a) if a.new_owner().is_none() => return,
            Ok(_) => {}
            Err(_) => return,
        }
    }
}

/// Unique names whose departure is being watched (one watch each).
#[derive(Debug, Clone, Default)]
pub struct Watched(Arc<Mutex<HashSet<String>>>);

impl Watched {
    /// Adds `name`; false when it was watched already.
    pub fn insert(&self, name: &str) -> bool {
        self.lock().insert(name.to_owned())
    }

    pub fn remove(&self, name: &str) {
        self.lock().remove(name);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashSet<String>> {
        match self.0.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        }
    }
}
