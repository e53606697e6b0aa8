//! The frame clock of sources without one of their own (the simulator, a
//! replayed recording): when the next capture is due. The frame loop waits
//! for it on its command channel, so a command wakes it at once.

use std::time::{Duration, Instant};

#[derive(Debug, Default)]
pub struct Pacer {
    /// When the last capture was due (or made, after a restart).
    last: Option<Instant>,
}

/// One frame period at `rate_hz` (clamped to [1e-3, 1e6] Hz).
fn period(rate_hz: f64) -> Duration {
    Duration::from_secs_f64(1.0 / rate_hz.clamp(1e-3, 1e6))
}

impl Pacer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Time left at `now` until the next capture at `rate_hz`: measured from
    /// the last one with the current rate, so a new rate takes effect at once.
    pub fn remaining(&self, rate_hz: f64, now: Instant) -> Duration {
        match self.last {
            Some(t) => (t + period(rate_hz)).saturating_duration_since(now),
            None => Duration::ZERO,
        }
    }

    /// A capture was made at `now`: the clock ticks on from its due time; a
    /// capture more than a period late (or early) restarts the clock at `now`
    /// instead of bursting to catch up.
    pub fn tick(&mut self, rate_hz: f64, now: Instant) {
        let p = period(rate_hz);
        self.last = Some(match self.last.map(|t| t + p) {
            Some(due) if due <= now && now - due < p => due,
            _ => now,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_rate_takes_effect_at_once() {
        let t0 = Instant::now();
        let mut p = Pacer::new();
        assert_eq!(p.remaining(0.1, t0), Duration::ZERO);
        p.tick(0.1, t0);
        assert_eq!(p.remaining(0.1, t0), Duration::from_secs(10));
        // Back to 60 Hz: due one 60 Hz period after the last capture, not 10 s.
        assert_eq!(
            p.remaining(60.0, t0 + Duration::from_millis(20)),
            Duration::ZERO
        );
        assert!(p.remaining(60.0, t0) <= Duration::from_millis(17));
    }

    #[test]
    fn keeps_cadence_and_restarts_when_late() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut p = Pacer::new();
        p.tick(10.0, t0);
        // 5 ms late: the next is due at 200 ms, not 205.
        p.tick(10.0, t0 + ms(105));
        assert_eq!(p.remaining(10.0, t0 + ms(105)), ms(95));
        // Half a second late: restart, no burst.
        p.tick(10.0, t0 + ms(800));
        assert_eq!(p.remaining(10.0, t0 + ms(800)), ms(100));
        // Early (a command asked for a frame now): restart at that capture.
        p.tick(10.0, t0 + ms(850));
        assert_eq!(p.remaining(10.0, t0 + ms(850)), ms(100));
    }
}
