//! Sleeps until the next frame deadline, like a sensor's frame clock.

use std::time::{Duration, Instant};

pub struct Pacer {
    next: Option<Instant>,
}

impl Pacer {
    pub fn new() -> Self {
        Self { next: None }
    }

    /// Waits for the next tick of a clock at `rate_hz`; a late caller
    /// restarts the clock instead of bursting to catch up.
    pub fn wait(&mut self, rate_hz: f64) {
        let period = Duration::from_secs_f64(1.0 / rate_hz.clamp(1e-3, 1e6));
        let now = Instant::now();
        let next = match self.next {
            Some(t) if t > now => {
                std::thread::sleep(t - now);
                t
            }
            Some(t) if now - t < period => t,
            _ => now,
        };
        self.next = Some(next + period);
    }
}

impl Default for Pacer {
    fn default() -> Self {
        Self::new()
    }
}
