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
    /// When the last frame was captured (None before the first).
    pub last_frame_at: Option<Instant>,
    /// Why the source delivers no frames now (end of recording, device
    /// unavailable); None while it does.
    pub stalled: Option<&'static str>,
}

impl Stats {
    /// The frame rate as of `now`: 0 once no frame came for longer than
    /// [`stale_after`] of the `frame_rate_hz` asked for, or while stalled.
    pub fn fps_at(&self, now: Instant, frame_rate_hz: f64) -> f64 {
        match self.last_frame_at {
            Some(t) if self.stalled.is_none() && now - t <= stale_after(frame_rate_hz) => self.fps,
            _ => 0.0,
        }
    }
}

/// How long without a frame before the frame rate reads 0: three frame
/// periods, and at least 2 s.
pub fn stale_after(frame_rate_hz: f64) -> Duration {
    Duration::from_secs_f64((3.0 / frame_rate_hz.max(1e-3)).clamp(2.0, 3600.0))
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
        self.current.last_frame_at = Some(Instant::now());
        self.current.stalled = None;
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

impl StatsWindow {
    /// The source delivers no frames (`why`): the frame rate is 0 until
    /// frames come again, and the next window starts then.
    pub fn stalled(&mut self, why: &'static str) {
        self.current.fps = 0.0;
        self.current.stalled = Some(why);
        self.start = Instant::now();
        self.frames = 0;
        self.latency_sum_us = 0.0;
        self.latency_max_us = 0.0;
    }
}

impl Default for StatsWindow {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fps_reads_zero_when_frames_stop() {
        let mut w = StatsWindow::new();
        w.current.fps = 60.0;
        w.current.last_frame_at = Some(Instant::now());
        let now = Instant::now();
        assert_eq!(w.current.fps_at(now, 60.0), 60.0);
        assert_eq!(w.current.fps_at(now + Duration::from_secs(3), 60.0), 0.0);
        // At 0.1 fps a frame every 10 s is not stale.
        assert_eq!(w.current.fps_at(now + Duration::from_secs(12), 0.1), 60.0);
        w.stalled("end of recording");
        assert_eq!(w.current.fps_at(now, 60.0), 0.0);
        assert_eq!(Stats::default().fps_at(now, 60.0), 0.0);
    }
}
