//! Log-on-change per cause: one line when a cause first shows, then at most
//! one per [`REPEAT_INTERVAL`] saying how often it came back meanwhile.
//!
//! A device on the board's USB IDs decides how often sdid fails (a
//! re-enumeration storm, a stall on every transfer): the log must not grow
//! with it. Hand-written: a map and a clock; no crate in the workspace's tree
//! rate-limits tracing events per key.

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// How long a cause already logged stays quiet.
pub const REPEAT_INTERVAL: Duration = Duration::from_secs(60);
/// Causes remembered at once; a device that makes up new ones cannot grow
/// the map past this (it is cleared instead).
pub const MAX_CAUSES: usize = 64;

#[derive(Debug, Clone, Copy)]
struct Seen {
    logged_at: Instant,
    /// Occurrences not logged since `logged_at`.
    quiet: u64,
}

/// When to log each cause.
#[derive(Debug, Default)]
pub struct CauseLog {
    seen: HashMap<String, Seen>,
}

impl CauseLog {
    /// Notes one occurrence of `cause` at `now`. `Some(n)` when a line is
    /// due, `n` being the occurrences kept quiet since the last line; `None`
    /// while the cause is quiet.
    pub fn admit_at(&mut self, cause: &str, now: Instant) -> Option<u64> {
        if let Some(s) = self.seen.get_mut(cause) {
            if now.saturating_duration_since(s.logged_at) < REPEAT_INTERVAL {
                s.quiet += 1;
                return None;
            }
            let quiet = s.quiet;
            *s = Seen {
                logged_at: now,
                quiet: 0,
            };
            return Some(quiet);
        }
        if self.seen.len() >= MAX_CAUSES {
            self.seen.clear();
        }
        self.seen.insert(
            cause.to_owned(),
            Seen {
                logged_at: now,
                quiet: 0,
            },
        );
        Some(0)
    }

    /// [`CauseLog::admit_at`] now.
    pub fn admit(&mut self, cause: &str) -> Option<u64> {
        self.admit_at(cause, Instant::now())
    }

    /// Forgets `cause`: its next occurrence is logged at once (the
    /// condition ended, e.g. the board streams again).
    pub fn clear(&mut self, cause: &str) {
        self.seen.remove(cause);
    }
}

/// " (N more times since the last line)" when `quiet` > 0, else "".
pub fn repeats(quiet: u64) -> String {
    if quiet == 0 {
        String::new()
    } else {
        format!(
            " ({quiet} more time{} in the last {} s)",
            if quiet == 1 { "" } else { "s" },
            REPEAT_INTERVAL.as_secs()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_is_logged_once_per_interval_with_its_repeats() {
        let mut log = CauseLog::default();
        let t0 = Instant::now();
        assert_eq!(log.admit_at("stall", t0), Some(0));
        for i in 1..=1000 {
            assert_eq!(log.admit_at("stall", t0 + Duration::from_millis(i)), None);
        }
        // another cause is not held back by the first
        assert_eq!(log.admit_at("short reply", t0), Some(0));
        assert_eq!(log.admit_at("stall", t0 + REPEAT_INTERVAL), Some(1000));
        assert_eq!(
            log.admit_at("stall", t0 + REPEAT_INTERVAL + Duration::from_secs(1)),
            None
        );
        log.clear("stall");
        assert_eq!(
            log.admit_at("stall", t0 + REPEAT_INTERVAL + Duration::from_secs(2)),
            Some(0)
        );
        assert_eq!(repeats(0), "");
        assert_eq!(repeats(1), " (1 more time in the last 60 s)");
    }

    #[test]
    fn made_up_causes_do_not_grow_the_map() {
        let mut log = CauseLog::default();
        let t0 = Instant::now();
        for i in 0..10_000 {
            assert_eq!(log.admit_at(&format!("cause {i}"), t0), Some(0));
            assert!(log.seen.len() <= MAX_CAUSES);
        }
    }
}
