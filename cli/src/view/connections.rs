//! The page's server's connections: how long each may sit and how many may
//! wait for a token.
//!
//! Anyone on the machine can connect to 127.0.0.1 without the token, so
//! nothing a connection costs may be unbounded:
//!
//! - **Timeouts** ([`Limits::timeout`], 10 s): a request's headers must
//!   arrive within it, counted from the connection's start or, on a
//!   kept-alive connection, from the end of the previous response (hyper's
//!   header read timeout, so an idle connection is closed after it too),
//!   and a request's body within it once its headers are read
//!   ([`read_body`]; at most [`MAX_BODY`] bytes).
//! - **A cap on connections that have shown no token** ([`Limits::waiting`],
//!   32): a new connection over the cap closes the *oldest* waiting one
//!   rather than being refused, so idle connections cannot hold the door
//!   shut against the page; a flood has to outpace the browser's own
//!   request on every new connection. A connection leaves the waiting set
//!   when a request on it passes the token check ([`Admission::trust`]);
//!   such connections (the page's fetches and its WebSocket) are not
//!   counted, as only the user holds the token. So descriptors stay bounded
//!   by the cap plus the page's own connections.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::StatusCode;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Router;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::Notify;
use tower::ServiceExt;

use crate::exit::CliError;

/// The largest request body read: the page's requests are a few bytes of JSON.
pub const MAX_BODY: usize = 64 * 1024;

/// How long a connection may take and how many may wait (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub timeout: Duration,
    pub waiting: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(10),
            waiting: 32,
        }
    }
}

impl Limits {
    /// The defaults, with the timeout from `SDI_VIEW_TIMEOUT_MS` when set
    /// (for the tests).
    pub fn from_env() -> Result<Self, CliError> {
        let mut limits = Self::default();
        if let Some(ms) = std::env::var_os("SDI_VIEW_TIMEOUT_MS") {
            let ms: u64 = ms
                .to_str()
                .and_then(|s| s.parse().ok())
                .filter(|&ms| ms > 0)
                .ok_or_else(|| {
                    CliError::Usage(format!(
                        "SDI_VIEW_TIMEOUT_MS={ms:?}: expected milliseconds > 0"
                    ))
                })?;
            limits.timeout = Duration::from_millis(ms);
        }
        Ok(limits)
    }
}

/// The connections that have shown no token yet, oldest first.
struct Waiting {
    cap: usize,
    inner: Mutex<(u64, BTreeMap<u64, Arc<Notify>>)>,
}

impl Waiting {
    /// Enters a new connection, closing the oldest waiting one at the cap.
    fn admit(self: &Arc<Self>) -> (Admission, Arc<Notify>) {
        let close = Arc::new(Notify::new());
        let mut inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        while inner.1.len() >= self.cap {
            match inner.1.pop_first() {
                Some((_, oldest)) => oldest.notify_one(),
                None => break,
            }
        }
        let id = inner.0;
        inner.0 += 1;
        inner.1.insert(id, close.clone());
        let ticket = Ticket {
            id,
            waiting: self.clone(),
        };
        (Admission(Arc::new(ticket)), close)
    }

    fn leave(&self, id: u64) {
        self.inner
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .1
            .remove(&id);
    }
}

struct Ticket {
    id: u64,
    waiting: Arc<Waiting>,
}

impl Drop for Ticket {
    fn drop(&mut self) {
        self.waiting.leave(self.id);
    }
}

/// A connection's place among the waiting ones, in each of its requests'
/// extensions for the token check.
#[derive(Clone)]
pub struct Admission(Arc<Ticket>);

impl Admission {
    /// The connection showed the token: it no longer counts nor is closed
    /// for newcomers.
    pub fn trust(&self) {
        self.0.waiting.leave(self.0.id);
    }
}

/// Serves `router` on `listener` under `limits` until an error of the
/// listener itself.
pub async fn serve(listener: TcpListener, router: Router, limits: Limits) -> std::io::Result<()> {
    let waiting = Arc::new(Waiting {
        cap: limits.waiting,
        inner: Mutex::new((0, BTreeMap::new())),
    });
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            // Out of descriptors or a connection reset before it was
            // taken: wait a little rather than spin, and go on.
            Err(e) => {
                eprintln!("sdictl view: accepting a connection: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let (admission, close) = waiting.admit();
        let service = router
            .clone()
            .map_request(move |req: axum::http::Request<Incoming>| {
                let mut req = req.map(Body::new);
                req.extensions_mut().insert(admission.clone());
                req
            });
        tokio::spawn(async move {
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(limits.timeout);
            let conn = builder
                .serve_connection(TokioIo::new(stream), TowerToHyperService::new(service))
                .with_upgrades();
            // Dropping the connection closes it.
            tokio::select! {
                _ = conn => {}
                _ = close.notified() => {}
            }
        });
    }
}

/// Reads a request's body within the timeout (408 otherwise; 413 beyond
/// [`MAX_BODY`]) before the handler runs (behind the token check).
pub async fn read_body(State(limits): State<Limits>, req: Request, next: Next) -> Response {
    let (parts, body) = req.into_parts();
    let bytes = match tokio::time::timeout(limits.timeout, axum::body::to_bytes(body, MAX_BODY))
        .await
    {
        Ok(Ok(bytes)) => bytes,
        Ok(Err(_)) => {
            return (StatusCode::PAYLOAD_TOO_LARGE, "request body too large\n").into_response()
        }
        Err(_) => return (StatusCode::REQUEST_TIMEOUT, "request body timed out\n").into_response(),
    };
    next.run(Request::from_parts(parts, Body::from(bytes)))
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_oldest_waiting_connection_makes_room_and_trusted_ones_do_not_count() {
        let waiting = Arc::new(Waiting {
            cap: 2,
            inner: Mutex::new((0, BTreeMap::new())),
        });
        let (a, a_close) = waiting.admit();
        let (b, _b_close) = waiting.admit();
        b.trust();
        let (_c, c_close) = waiting.admit();
        let (_d, _) = waiting.admit();
        // a was the oldest waiting when d came; b is trusted, c still waits.
        let closed = |n: &Arc<Notify>| {
            let f = n.notified();
            tokio::pin!(f);
            f.as_mut().enable()
        };
        assert!(closed(&a_close));
        assert!(!closed(&c_close));
        drop(a);
        assert_eq!(waiting.inner.lock().unwrap().1.len(), 2);
    }
}
