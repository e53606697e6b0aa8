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

/// [`left_bus`] in a task of its own, aborted when this is dropped.
///
/// Polling it drives no bus I/O, so it may sit beside other futures in a
/// `select!` whose branch bodies send. `left_bus` itself must not: it
/// sends (AddMatch, NameHasOwner), and zbus hands its connection-wide
/// write lock out in turn; a `left_bus` that queued for the lock and is
/// then left unpolled (while a branch body awaits a send of its own,
/// queued behind it) is granted the lock and never releases it: every
/// send of sdid waits forever, method replies and `Peer.Ping` included.
/// That stalled running jobs (`job_step` publishing progress) under load.
pub struct Departure {
    watch: tokio::task::JoinHandle<()>,
    /// The name has left (stays ready: a finished task is not polled again).
    left: bool,
}

impl Departure {
    /// Starts watching `name` on `conn`.
    pub fn watch(conn: Connection, name: OwnedUniqueName) -> Self {
        Self {
            watch: tokio::spawn(left_bus(conn, name)),
            left: false,
        }
    }
}

impl std::future::Future for Departure {
    type Output = ();

    /// Ready once the name has left (or the watch failed: counted as gone,
    /// as in [`left_bus`]).
    fn poll(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<()> {
        if !self.left {
            std::task::ready!(std::pin::Pin::new(&mut self.watch).poll(cx)).ok();
            self.left = true;
        }
        std::task::Poll::Ready(())
    }
}

impl Drop for Departure {
    fn drop(&mut self) {
        self.watch.abort();
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
