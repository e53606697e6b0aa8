//! Who may use the page: every request and WebSocket must carry the random
//! token of the URL sdictl printed, name this server in `Host` (no DNS
//! rebinding: a foreign name resolving to 127.0.0.1 is refused) and, when it
//! has an `Origin`, come from this server's origin (no cross-site request).
//! Requests that change something must have an `Origin`; anything else
//! gets 403 and changes nothing.

use axum::extract::{Request, State};
use axum::http::{header, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

/// The secret in the page's URL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Token(String);

impl Token {
    /// 128 random bits from the operating system's generator, as hex.
    pub fn random() -> Self {
        let bits: u128 = rand::random();
        Self(format!("{bits:032x}"))
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// Compares in time independent of where the first difference is.
    fn matches(&self, given: &str) -> bool {
        let (a, b) = (self.0.as_bytes(), given.as_bytes());
        a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
    }
}

/// What a request must match.
#[derive(Debug, Clone)]
pub struct Guard {
    pub token: Token,
    pub port: u16,
}

impl Guard {
    fn host_ok(&self, host: &str) -> bool {
        [
            format!("127.0.0.1:{}", self.port),
            format!("localhost:{}", self.port),
        ]
        .iter()
        .any(|h| h.eq_ignore_ascii_case(host))
    }

    fn origin_ok(&self, origin: &str) -> bool {
        [
            format!("http://127.0.0.1:{}", self.port),
            format!("http://localhost:{}", self.port),
        ]
        .iter()
        .any(|o| o.eq_ignore_ascii_case(origin))
    }

    /// Whether `req` may be served.
    pub fn allows(&self, req: &Request) -> bool {
        let text = |name: header::HeaderName| {
            req.headers()
                .get(name)
                .and_then(|v| v.to_str().ok())
                .map(str::to_owned)
        };
        let token_ok = req
            .uri()
            .query()
            .into_iter()
            .flat_map(|q| q.split('&'))
            .filter_map(|kv| kv.strip_prefix("token="))
            .any(|t| self.token.matches(t));
        let host_ok = text(header::HOST).is_some_and(|h| self.host_ok(&h));
        let is_websocket = req.headers().contains_key(header::UPGRADE);
        let needs_origin = is_websocket || req.method() != Method::GET;
        let origin_ok = match text(header::ORIGIN) {
            Some(o) => self.origin_ok(&o),
            None => !needs_origin,
        };
        token_ok && host_ok && origin_ok
    }
}

/// The middleware in front of every route.
pub async fn check(State(guard): State<Guard>, req: Request, next: Next) -> Response {
    if guard.allows(&req) {
        next.run(req).await
    } else {
        (StatusCode::FORBIDDEN, "forbidden\n").into_response()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;

    fn guard() -> Guard {
        Guard {
            token: Token("00ff".into()),
            port: 8080,
        }
    }

    fn req(method: Method, uri: &str, headers: &[(&str, &str)]) -> Request {
        let mut b = Request::builder().method(method).uri(uri);
        for (k, v) in headers {
            b = b.header(*k, *v);
        }
        b.body(Body::empty()).unwrap()
    }

    #[test]
    fn token_host_and_origin_are_all_required() {
        let g = guard();
        let host = ("host", "127.0.0.1:8080");
        let origin = ("origin", "http://127.0.0.1:8080");
        assert!(g.allows(&req(Method::GET, "/?token=00ff", &[host])));
        assert!(g.allows(&req(Method::POST, "/api?token=00ff", &[host, origin])));
        assert!(!g.allows(&req(Method::GET, "/", &[host])));
        assert!(!g.allows(&req(Method::GET, "/?token=00fe", &[host])));
        assert!(!g.allows(&req(Method::GET, "/?token=00f", &[host])));
        assert!(!g.allows(&req(Method::GET, "/?token=00ff", &[("host", "evil:8080")])));
        assert!(!g.allows(&req(Method::GET, "/?token=00ff", &[])));
        let evil = ("origin", "http://evil.example");
        assert!(!g.allows(&req(Method::GET, "/?token=00ff", &[host, evil])));
        // Changes and WebSockets need the Origin.
        assert!(!g.allows(&req(Method::POST, "/api?token=00ff", &[host])));
        let ws = ("upgrade", "websocket");
        assert!(!g.allows(&req(Method::GET, "/ws?token=00ff", &[host, ws])));
        assert!(g.allows(&req(Method::GET, "/ws?token=00ff", &[host, ws, origin])));
    }

    #[test]
    fn tokens_are_random_hex() {
        let (a, b) = (Token::random(), Token::random());
        assert_ne!(a, b);
        assert_eq!(a.as_str().len(), 32);
    }
}
