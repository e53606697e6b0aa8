//! Frame-loop statistics published to D-Bus.

use std::time::{Duration, Instant};

/// A snapshot of the frame loop's health.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stats {
    /// Frames captured since start.
    pub frames: u64,
    /// Frames per second over the last window.
    pub fps: f64,
    /// Mean capture-to-output processing time over the last window, microseconds.
    pub latency_us: f64,
    /// Worst processing time over the last window, microseconds.
    pub latency_max_us: f64,
    /// Frames the view output skipped (reader too slow).
    pub dropped_view: u64,
    /// Frames the recorder could not queue.
    pub dropped_recording: u64,
}

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
