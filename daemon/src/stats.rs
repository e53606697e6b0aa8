//! Frame-loop statistics published to D-Bus. The `Stats` property has one
//! definition, [`sdi_api::Stats`]: the frame loop fills its timing and drop
//! counters, the D-Bus object the device state and the recorder's stop
//! reason.

use std::time::{Duration, Instant};

pub use sdi_api::Stats;

/// What the frame loop publishes: the counters of [`Stats`] it owns (the
/// D-Bus object adds device state and stop reason), plus what it takes to
/// tell a stale frame rate when Stats is read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoopStats {
    /// frames, fps, latency and drop counters.
    pub counters: Stats,
    /// When the last frame was captured (None before the first).
    pub last_frame_at: Option<Instant>,
    /// Why the source delivers no frames now (end of recording, device
    /// unavailable); None while it does.
    pub stalled: Option<&'static str>,
}

impl LoopStats {
    /// The frame rate as of `now`: 0 once no frame came for longer than
    /// [`stale_after`] of the `frame_rate_hz` asked for, or while stalled.
    pub fn fps_at(&self, now: Instant, frame_rate_hz: f64) -> f64 {
        match self.last_frame_at {
            Some(t) if self.stalled.is_none() && now - t <= stale_after(frame_rate_hz) => {
                self.counters.fps
            }
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
    pub current: LoopStats,
}

pub const WINDOW: Duration = Duration::from_millis(500);

impl StatsWindow {
    pub fn new() -> Self {
        Self {
            start: Instant::now(),
            frames: 0,
            latency_sum_us: 0.0,
            latency_max_us: 0.0,
            current: LoopStats::default(),
        }
    }

    /// Records one frame; returns true when a window closed and `current` was updated.
    pub fn frame(&mut self, latency: Duration) -> bool {
        let us = latency.as_secs_f64() * 1e6;
        self.current.last_frame_at = Some(Instant::now());
        self.current.stalled = None;
        self.current.counters.frames += 1;
        self.frames += 1;
        self.latency_sum_us += us;
        self.latency_max_us = self.latency_max_us.max(us);
        let elapsed = self.start.elapsed();
        if elapsed < WINDOW {
            return false;
        }
        let c = &mut self.current.counters;
        c.fps = self.frames as f64 / elapsed.as_secs_f64();
        c.latency_us = self.latency_sum_us / self.frames as f64;
        c.latency_max_us = self.latency_max_us;
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
        self.current.counters.fps = 0.0;
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
        w.current.counters.fps = 60.0;
        w.current.last_frame_at = Some(Instant::now());
        let now = Instant::now();
        assert_eq!(w.current.fps_at(now, 60.0), 60.0);
        assert_eq!(w.current.fps_at(now + Duration::from_secs(3), 60.0), 0.0);
        // At 0.1 fps a frame every 10 s is not stale.
        assert_eq!(w.current.fps_at(now + Duration::from_secs(12), 0.1), 60.0);
        w.stalled("end of recording");
        assert_eq!(w.current.fps_at(now, 60.0), 0.0);
        assert_eq!(LoopStats::default().fps_at(now, 60.0), 0.0);
    }
}
