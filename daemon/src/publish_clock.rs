//! The one clock of everything the sinks publish. The frame loop stamps each
//! captured frame and each "no signal" card here, on CLOCK_MONOTONIC
//! microseconds (the clock of V4L2 buffer timestamps), and the sinks write
//! the stamp they are given. The rule, per published stream:
//!
//! - a frame is stamped with its capture time, a card with the moment the
//!   frame loop decides to show it, so neither is ever in a reader's future
//!   (a stamp is never later than "now" when it is chosen);
//! - stamps strictly increase in the order they are chosen, whichever kind,
//!   so a card shown between two frames lies between them, and a card is
//!   never later than the capture of the next frame;
//! - the card a loopback writer shows from its open is stamped at the open,
//!   before the frame loop starts, so before every stamp from here.

/// Issues the publish timestamps, microseconds of CLOCK_MONOTONIC.
#[derive(Debug, Default)]
pub struct PublishClock {
    last_us: Option<u64>,
}

impl PublishClock {
    /// The stamp of a frame captured at `captured_us` (already on
    /// CLOCK_MONOTONIC), chosen at `now_us`: the capture time, kept no later
    /// than now and after every stamp chosen before.
    pub fn frame(&mut self, captured_us: u64, now_us: u64) -> u64 {
        self.next(captured_us.min(now_us))
    }

    /// The stamp of a "no signal" card the frame loop shows at `now_us`.
    pub fn no_signal(&mut self, now_us: u64) -> u64 {
        self.next(now_us)
    }

    /// `t_us`, or one microsecond after the last stamp if that is not earlier.
    fn next(&mut self, t_us: u64) -> u64 {
        let t_us = match self.last_us {
            Some(last) => t_us.max(last.saturating_add(1)),
            None => t_us,
        };
        self.last_us = Some(t_us);
        t_us
    }
}

#[cfg(test)]
mod tests {
    use super::PublishClock;

    /// Stamps of (is_card, event time, now when chosen) in order: each is
    /// strictly after the previous and, where the previous stamp left room,
    /// not later than now.
    fn check(events: &[(bool, u64, u64)]) -> Vec<u64> {
        let mut c = PublishClock::default();
        let stamps: Vec<u64> = events
            .iter()
            .map(|&(card, t, now)| {
                if card {
                    c.no_signal(now)
                } else {
                    c.frame(t, now)
                }
            })
            .collect();
        for (w, e) in stamps.windows(2).zip(&events[1..]) {
            assert!(w[1] > w[0], "stamps {stamps:?} go back or repeat");
            assert!(
                w[1] <= e.2.max(w[0] + 1),
                "stamp {} in the future at {}",
                w[1],
                e.2
            );
        }
        stamps
    }

    #[test]
    fn no_signal_then_frames() {
        // Card at start-up, then frames whose capture started before they
        // were stamped (each capture took 20 ms).
        let s = check(&[
            (true, 0, 1_000),
            (false, 1_500, 21_500),
            (false, 34_833, 54_833),
            (false, 68_166, 88_166),
        ]);
        assert_eq!(s, [1_000, 1_500, 34_833, 68_166]);
    }

    #[test]
    fn frames_then_pause_then_no_signal_then_frames() {
        let s = check(&[
            (false, 10_000, 30_000),
            (false, 43_333, 63_333),
            // the source stalls: a card at 70 ms, another 200 ms later
            (true, 0, 70_000),
            (true, 0, 270_000),
            // it is back: captured at 470 ms, and one in the card's microsecond
            (false, 470_000, 490_000),
            (true, 0, 500_000),
            (false, 500_000, 500_000),
        ]);
        assert_eq!(
            s,
            [10_000, 43_333, 70_000, 270_000, 470_000, 500_000, 500_001]
        );
    }

    #[test]
    fn a_source_stamp_ahead_of_now_is_held_to_now() {
        let mut c = PublishClock::default();
        assert_eq!(c.frame(5_000, 4_000), 4_000);
        // and a stamp earlier than the last one chosen moves after it
        assert_eq!(c.frame(3_000, 6_000), 4_001);
    }
}
