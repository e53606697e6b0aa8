//! Who may use the page: every request and WebSocket must carry the random
//! token (which reaches the browser through `redirect`), name this server
//! in `Host` (no DNS rebinding: a foreign name resolving to 127.0.0.1 is
//! refused) and, when it has an `Origin`, come from this server's origin
//! (no cross-site request). Requests that change something must have an
//! `Origin`; anything else gets 403 and changes nothing. The one exception
//! to the token is `GET /`, the page itself: static, holding no secret, and
//! loaded with the token in the URL's fragment, which is never sent. A
//! request that passes with the token marks its connection trusted
//! (`connections::Admission`).

use axum::extract::{Request, State};
use axum::http::{header, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::connections::Admission;

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

    /// Whether `req` may be served, and how.
    pub fn allows(&self, req: &Request) -> Access {
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
        let is_page = req.method() == Method::GET && req.uri().path() == "/" && !is_websocket;
        match (host_ok && origin_ok, token_ok, is_page) {
            (true, true, _) => Access::Token,
            (true, false, true) => Access::Page,
            _ => Access::Refused,
        }
    }
}

/// What the guard lets a request do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Everything: it carries the token.
    Token,
    /// Load the page only.
    Page,
    /// Nothing: 403.
    Refused,
}

/// The middleware in front of every route.
pub async fn check(State(guard): State<Guard>, req: Request, next: Next) -> Response {
    match guard.allows(&req) {
        Access::Token => {
            if let Some(a) = req.extensions().get::<Admission>() {
                a.trust();
            }
            next.run(req).await
        }
        Access::Page => next.run(req).await,
        Access::Refused => (StatusCode::FORBIDDEN, "forbidden\n").into_response(),
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
        let allows = |m, uri, h: &[(&str, &str)]| g.allows(&req(m, uri, h)) == Access::Token;
        assert!(allows(Method::GET, "/api/status?token=00ff", &[host]));
        assert!(allows(Method::POST, "/api?token=00ff", &[host, origin]));
        assert!(!allows(Method::GET, "/api/status", &[host]));
        assert!(!allows(Method::GET, "/api/status?token=00fe", &[host]));
        assert!(!allows(Method::GET, "/api/status?token=00f", &[host]));
        let evil_host = ("host", "evil:8080");
        assert!(!allows(Method::GET, "/api/status?token=00ff", &[evil_host]));
        assert!(!allows(Method::GET, "/api/status?token=00ff", &[]));
        let evil = ("origin", "http://evil.example");
        assert!(!allows(
            Method::GET,
            "/api/status?token=00ff",
            &[host, evil]
        ));
        // Changes and WebSockets need the Origin.
        assert!(!allows(Method::POST, "/api?token=00ff", &[host]));
        let ws = ("upgrade", "websocket");
        assert!(!allows(Method::GET, "/ws?token=00ff", &[host, ws]));
        assert!(allows(Method::GET, "/ws?token=00ff", &[host, ws, origin]));
        // The page itself needs no token, but this server's Host and Origin.
        let page = |h: &[(&str, &str)]| g.allows(&req(Method::GET, "/", h));
        assert_eq!(page(&[host]), Access::Page);
        assert_eq!(page(&[host, origin]), Access::Page);
        assert_eq!(page(&[evil_host]), Access::Refused);
        assert_eq!(page(&[host, evil]), Access::Refused);
        assert_eq!(page(&[host, ws, origin]), Access::Refused);
        assert_eq!(
            g.allows(&req(Method::POST, "/", &[host, origin])),
            Access::Refused
        );
    }

    #[test]
    fn tokens_are_random_hex() {
        let (a, b) = (Token::random(), Token::random());
        assert_ne!(a, b);
        assert_eq!(a.as_str().len(), 32);
    }
}
