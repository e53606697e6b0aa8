//! A device's frame timestamps on the system's monotonic clock
//! (CLOCK_MONOTONIC, microseconds), as V4L2 capture drivers stamp buffers. A
//! backend's own clock starts anywhere and may restart (a board reopened);
//! each start is anchored to the monotonic time of its first frame, never
//! earlier than one frame period after the last timestamp sent, and the
//! backend's own spacing is kept in between. Sources the frame loop paces
//! (simulator, replay) need no mapping: their stamp is the monotonic time of
//! their capture (a stamp already on the monotonic clock would pass through
//! unchanged). What is published is stamped by `crate::publish_clock`.

/// Maps backend timestamps onto the monotonic timeline, microseconds.
#[derive(Debug, Default)]
pub struct MonotonicClock {
    offset_us: i128,
    last_in_us: Option<u64>,
    last_out_us: Option<u64>,
}

/// CLOCK_MONOTONIC now, microseconds (0 if the clock cannot be read).
pub fn monotonic_now_us() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() as u64 * 1_000_000 + t.tv_nsec() as u64 / 1000)
        .unwrap_or(0)
}

impl MonotonicClock {
    /// The output timestamp of a frame the backend stamped `t_us`, captured
    /// at monotonic time `now_us` (for a stamp already on the monotonic
    /// clock, `now_us == t_us`: it passes through unchanged).
    pub fn map(&mut self, t_us: u64, period_us: u64, now_us: u64) -> u64 {
        let restarted = match self.last_in_us {
            Some(last_in) => t_us < last_in,
            None => true,
        };
        if restarted {
            let floor = self
                .last_out_us
                .map_or(0, |last| last.saturating_add(period_us));
            self.offset_us = i128::from(now_us.max(floor)) - i128::from(t_us);
        }
        self.last_in_us = Some(t_us);
        let mut out = (i128::from(t_us) + self.offset_us).clamp(0, i128::from(u64::MAX)) as u64;
        if let Some(last) = self.last_out_us {
            // A backend clock that stands still never repeats a timestamp.
            out = out.max(last.saturating_add(1));
        }
        self.last_out_us = Some(out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchored_to_the_monotonic_clock_and_continues_after_a_restart() {
        let mut c = MonotonicClock::default();
        let out: Vec<u64> = [
            (1000, 50_000),
            (2000, 51_000),
            (3000, 52_000),
            (0, 52_500),
            (1000, 53_700),
            (500, 54_000),
        ]
        .into_iter()
        .map(|(t, now)| c.map(t, 1000, now))
        .collect();
        // first start at now; the restart at 0 lands one period after the
        // last frame (later than now), so does the one at 500
        assert_eq!(out, [50_000, 51_000, 52_000, 53_000, 54_000, 55_000]);
    }

    #[test]
    fn a_stamp_on_the_monotonic_clock_passes_through() {
        let mut c = MonotonicClock::default();
        let out: Vec<u64> = [50_000, 83_333, 116_667, 116_900]
            .into_iter()
            .map(|t| c.map(t, 33_333, t))
            .collect();
        assert_eq!(out, [50_000, 83_333, 116_667, 116_900]);
    }

    #[test]
    fn a_stalled_backend_clock_still_advances() {
        let mut c = MonotonicClock::default();
        assert_eq!(c.map(7, 1000, 100), 100);
        assert_eq!(c.map(7, 1000, 200), 101);
    }
}
