//! Polling with a deadline: the one wait loop of the tests.

use std::time::{Duration, Instant};

/// How often a condition is polled.
const POLL: Duration = Duration::from_millis(50);

/// Polls `f` until it returns `Some`, and returns that; panics naming
/// `what` after `timeout`.
pub fn wait_for<T>(what: &str, timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let t0 = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(
            t0.elapsed() < timeout,
            "timed out after {timeout:?} waiting for {what}"
        );
        std::thread::sleep(POLL);
    }
}

/// [`wait_for`], and on the timeout the panic says what `seen()` returns
/// then (the state the wait was looking at).
pub fn wait_for_or<T>(
    what: &str,
    timeout: Duration,
    mut f: impl FnMut() -> Option<T>,
    seen: impl FnOnce() -> String,
) -> T {
    let t0 = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        if t0.elapsed() >= timeout {
            panic!(
                "timed out after {timeout:?} waiting for {what}; seen:\n{}",
                seen()
            );
        }
        std::thread::sleep(POLL);
    }
}

/// Polls `ready` until it holds, and returns how long that took; panics
/// naming `what` after `timeout`.
pub fn wait_until(what: &str, timeout: Duration, mut ready: impl FnMut() -> bool) -> Duration {
    let t0 = Instant::now();
    wait_for(what, timeout, || ready().then_some(()));
    t0.elapsed()
}
