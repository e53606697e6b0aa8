//! Frame-loop statistics published to D-Bus. The `Stats` property has one
//! definition, [`sdi_api::Stats`]: the frame loop fills its timing and drop
//! counters, the D-Bus object the device state and the recorder's stop
//! reason.

use std::time::{Duration, Instant};

pub use sdi_api::Stats;

/// Accumulates per-frame timings into windows of about one second.
pub struct StatsWindow {
    start: Instant,
    frames: u32,
    latency_sum_us: f64,
    latency_max_us: f64,
    pub current: Stats,
}

pub const WINDOW: Duration = Duration::from_millis(500);

impl StatsWindow {
    pub fn new() -> Self {
        Self {
            start: Instant::now(),
            frames: 0,
            latency_sum_us: 0.0,
            latency_max_us: 0.0,
            current: Stats::default(),
        }
    }

    /// Records one frame; returns true when a window closed and `current` was updated.
    pub fn frame(&mut self, latency: Duration) -> bool {
        let us = latency.as_secs_f64() * 1e6;
        self.current.frames += 1;
        self.frames += 1;
        self.latency_sum_us += us;
        self.latency_max_us = self.latency_max_us.max(us);
        let elapsed = self.start.elapsed();
        if elapsed < WINDOW {
            return false;
        }
        self.current.fps = self.frames as f64 / elapsed.as_secs_f64();
        self.current.latency_us = self.latency_sum_us / self.frames as f64;
        self.current.latency_max_us = self.latency_max_us;
        self.start = Instant::now();
        self.frames = 0;
        self.latency_sum_us = 0.0;
        self.latency_max_us = 0.0;
        true
    }
}

impl Default for StatsWindow {
    fn default() -> Self {
        Self::new()
    }
}
