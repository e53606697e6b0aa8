//! The viewer's D-Bus connection, made again when it is lost: the bus
//! drops a connection that sends what it refuses, and without a new one
//! every later call of the page would fail until sdictl restarts. A call
//! that fails on a lost connection is not repeated (it may have reached
//! sdid); the next call uses the new connection.

use std::future::Future;
use std::pin::Pin;

use tokio::sync::Mutex;

use crate::exit::CliError;

/// Makes a new connection (sdictl's own `connect`, or a test's).
pub type Connect<T> =
    Box<dyn Fn() -> Pin<Box<dyn Future<Output = Result<T, CliError>> + Send>> + Send + Sync>;

/// The connection in use (a proxy or a connection; cheap to clone) and how
/// to make another.
pub struct Link<T> {
    /// The connection, numbered so a loss seen by several calls at once
    /// connects again only once.
    current: Mutex<(u64, T)>,
    connect: Connect<T>,
}

impl<T: Clone> Link<T> {
    pub fn new(first: T, connect: Connect<T>) -> Self {
        Self {
            current: Mutex::new((0, first)),
            connect,
        }
    }

    /// Runs `call` on the current connection; when it fails because the
    /// connection is gone, connects again for the calls that follow.
    pub async fn call<R, F, Fut>(&self, call: F) -> Result<R, CliError>
    where
        F: FnOnce(T) -> Fut,
        Fut: Future<Output = Result<R, CliError>>,
    {
        let (generation, conn) = self.current.lock().await.clone();
        let result = call(conn).await;
        if let Err(e) = &result {
            if is_lost(e) {
                self.reconnect(generation).await;
            }
        }
        result
    }

    /// Uses `next` from now on (the page chose another camera).
    pub async fn replace(&self, next: T) {
        let mut current = self.current.lock().await;
        *current = (current.0 + 1, next);
    }

    /// Replaces connection `generation` unless another call already did;
    /// if the bus cannot be reached now, the next loss tries again.
    async fn reconnect(&self, generation: u64) {
        let mut current = self.current.lock().await;
        if current.0 != generation {
            return;
        }
        match (self.connect)().await {
            Ok(conn) => *current = (generation + 1, conn),
            Err(e) => eprintln!("sdictl view: connecting to the bus again: {e}"),
        }
    }
}

/// Whether `e` says the connection to the bus is gone (closed by the bus,
/// or its socket failed), rather than that a call was refused.
pub fn is_lost(e: &CliError) -> bool {
    matches!(e, CliError::Bus(zbus::Error::InputOutput(_)))
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex as StdMutex};

    use super::*;

    struct Echo;

    #[zbus::interface(name = "org.example.Echo")]
    impl Echo {
        fn ping(&self) {}
    }

    /// A peer-to-peer connection and the server end that answers it.
    async fn pair() -> (zbus::Connection, zbus::Connection) {
        let (a, b) = tokio::net::UnixStream::pair().unwrap();
        let guid = zbus::Guid::generate();
        let server = zbus::connection::Builder::unix_stream(a)
            .server(guid)
            .unwrap()
            .p2p()
            .serve_at("/", Echo)
            .unwrap()
            .build();
        let client = zbus::connection::Builder::unix_stream(b).p2p().build();
        let (server, client) = tokio::join!(server, client);
        (client.unwrap(), server.unwrap())
    }

    async fn ping(conn: zbus::Connection) -> Result<(), CliError> {
        let call = conn.call_method(None::<&str>, "/", Some("org.example.Echo"), "Ping", &());
        tokio::time::timeout(std::time::Duration::from_secs(10), call)
            .await
            .map_err(|_| CliError::Runtime("ping timed out".into()))??;
        Ok(())
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_lost_connection_is_replaced_for_the_next_call() {
        let servers = Arc::new(StdMutex::new(Vec::new()));
        let (first, server) = pair().await;
        servers.lock().unwrap().push(server);
        let made = servers.clone();
        let link = Link::new(
            first,
            Box::new(move || {
                let made = made.clone();
                Box::pin(async move {
                    let (client, server) = pair().await;
                    made.lock().unwrap().push(server);
                    Ok(client)
                })
            }),
        );
        link.call(ping).await.unwrap();
        // The other end goes away, as when dbus-daemon drops the client.
        let gone = servers.lock().unwrap().remove(0);
        gone.close().await.unwrap();
        let lost = link.call(ping).await.unwrap_err();
        assert!(is_lost(&lost), "{lost:?}");
        link.call(ping).await.unwrap();
        assert_eq!(servers.lock().unwrap().len(), 1, "connected again once");
        // A refused call is not a loss.
        let refused = link
            .call(|c| async move {
                c.call_method(None::<&str>, "/", Some("org.example.None"), "X", &())
                    .await?;
                Ok(())
            })
            .await
            .unwrap_err();
        assert!(!is_lost(&refused), "{refused:?}");
        assert_eq!(servers.lock().unwrap().len(), 1);
    }
}
