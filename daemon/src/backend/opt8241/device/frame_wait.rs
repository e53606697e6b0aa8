//! The wait for one frame over consecutive `next_frame` calls: when to
//! wait on, yield ([`BoardError::NotYet`]) or give up ([`BoardError::NoFrame`]).

use std::time::{Duration, Instant};

use super::{BoardError, FRAME_WAIT, MAX_UNUSABLE_TRANSFERS};

/// The wait for one frame, spread over `next_frame` calls of at most
/// [`FRAME_SLICE`] each: what came instead of a frame so far, and when the
/// wait began.
#[derive(Debug, Clone)]
pub(super) struct FrameWait {
    since: Instant,
    /// What came instead, in a few words (the key of its log line).
    cause: &'static str,
    detail: String,
    /// Unusable transfers so far ([`MAX_UNUSABLE_TRANSFERS`]).
    unusable: u32,
}

/// What `next_frame` does next while waiting ([`FrameWait::step`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum WaitStep {
    /// Wait for the next stream event at most this long.
    Wait(Duration),
    /// The call's slice is over: [`BoardError::NotYet`].
    Yield,
    /// [`FRAME_WAIT`] is over, or too many transfers were unusable:
    /// [`BoardError::NoFrame`].
    GiveUp,
}

impl FrameWait {
    pub(super) fn new(since: Instant) -> Self {
        Self {
            since,
            cause: "no data",
            detail: "no data".into(),
            unusable: 0,
        }
    }

    /// At `now`, in a call whose slice ends at `slice_end`.
    pub(super) fn step(&self, slice_end: Instant, now: Instant) -> WaitStep {
        let deadline = self.since + FRAME_WAIT;
        if self.unusable >= MAX_UNUSABLE_TRANSFERS || now >= deadline {
            WaitStep::GiveUp
        } else if now >= slice_end {
            WaitStep::Yield
        } else {
            WaitStep::Wait(slice_end.min(deadline) - now)
        }
    }

    /// A transfer that cannot be part of a frame.
    pub(super) fn unusable(&mut self, cause: &'static str, detail: String) {
        self.unusable += 1;
        self.cause = cause;
        self.detail = detail;
    }

    /// The error that ends the wait at `now`.
    pub(super) fn no_frame(self, now: Instant) -> BoardError {
        BoardError::NoFrame {
            waited_ms: now.saturating_duration_since(self.since).as_millis(),
            cause: self.cause,
            detail: self.detail,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::FRAME_SLICE;
    use super::*;

    /// A silent device: each call yields after its slice, and the wait
    /// gives up once FRAME_WAIT is over, counted from the first call; a
    /// stream of unusable transfers gives up sooner.
    #[test]
    fn the_frame_wait_is_decided_over_slices() {
        let t0 = Instant::now();
        let mut w = FrameWait::new(t0);
        assert_eq!(w.step(t0 + FRAME_SLICE, t0), WaitStep::Wait(FRAME_SLICE));
        assert_eq!(w.step(t0 + FRAME_SLICE, t0 + FRAME_SLICE), WaitStep::Yield);
        // A call starting shortly before the deadline waits only up to it.
        let late = t0 + FRAME_WAIT - FRAME_SLICE / 4;
        assert_eq!(
            w.step(late + FRAME_SLICE, late),
            WaitStep::Wait(FRAME_SLICE / 4)
        );
        assert_eq!(
            w.step(late + FRAME_SLICE, t0 + FRAME_WAIT),
            WaitStep::GiveUp
        );
        let slices = FRAME_WAIT.as_millis() / FRAME_SLICE.as_millis();
        assert!(slices >= 10, "{slices} slices in the frame wait");
        for _ in 0..MAX_UNUSABLE_TRANSFERS {
            assert_eq!(w.step(t0 + FRAME_SLICE, t0), WaitStep::Wait(FRAME_SLICE));
            w.unusable("bulk endpoint halted", "halted".into());
        }
        assert_eq!(w.step(t0 + FRAME_SLICE, t0), WaitStep::GiveUp);
        match w.no_frame(t0 + FRAME_WAIT) {
            BoardError::NoFrame {
                waited_ms, cause, ..
            } => {
                assert_eq!(waited_ms, FRAME_WAIT.as_millis());
                assert_eq!(cause, "bulk endpoint halted");
            }
            other => panic!("{other:?}"),
        }
    }
}
