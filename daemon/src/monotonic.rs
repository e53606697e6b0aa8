//! Frame timestamps that never go backwards. A backend may restart its clock
//! (the simulator rebuilds itself for a new mode's scene); readers of the
//! output (ffmpeg, browsers) expect increasing timestamps, so after a restart
//! the stream continues one frame period after the last timestamp sent.

/// Maps backend timestamps onto one increasing timeline, microseconds.
#[derive(Debug, Default)]
pub struct MonotonicClock {
    offset_us: u64,
    last_in_us: Option<u64>,
    last_out_us: Option<u64>,
}

impl MonotonicClock {
    /// The output timestamp of a frame the backend stamped `t_us`.
    pub fn map(&mut self, t_us: u64, period_us: u64) -> u64 {
        if let (Some(last_in), Some(last_out)) = (self.last_in_us, self.last_out_us) {
            if t_us < last_in {
                self.offset_us = last_out.saturating_add(period_us).saturating_sub(t_us);
            }
        }
        self.last_in_us = Some(t_us);
        let out = t_us.saturating_add(self.offset_us);
        self.last_out_us = Some(out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn continues_after_a_restart() {
        let mut c = MonotonicClock::default();
        let out: Vec<u64> = [1000, 2000, 3000, 0, 1000, 500]
            .into_iter()
            .map(|t| c.map(t, 1000))
            .collect();
        assert_eq!(out, [1000, 2000, 3000, 4000, 5000, 6000]);
    }
}
