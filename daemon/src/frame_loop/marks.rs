//! Frame marks: a setting change is answered with the first frame
//! captured under it, once that frame's output has gone out.

use sdi_core::Frame;

use super::{FrameLoop, Reply};

/// The first frame produced under a new setting: every published output with
/// `sequence >= self.sequence` (and timestamp `>= self.timestamp_us`) was
/// captured under it, every one before under the old setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameMark {
    /// sdid's frame sequence number (one per capture, never reset).
    pub sequence: u64,
    /// Capture timestamp, microseconds: the V4L2 buffer timestamp readers see.
    /// 0 when the source delivers no frames (the mark is then the next one).
    pub timestamp_us: u64,
}

/// A reply waiting for the first output under a new setting.
pub(super) struct PendingMark {
    reply: Reply<FrameMark>,
    /// Set at the first capture after the setting was applied.
    captured: Option<FrameMark>,
}

impl FrameLoop {
    /// Notes the first capture under each pending setting change.
    pub(super) fn mark_capture(&mut self, frame: &Frame) {
        for p in self
            .pending_marks
            .iter_mut()
            .filter(|p| p.captured.is_none())
        {
            p.captured = Some(FrameMark {
                sequence: frame.sequence,
                timestamp_us: frame.timestamp_us,
            });
        }
    }

    /// Answers the setting changes whose first frame is in an output up to
    /// sequence `published` (`u64::MAX`: captured, and no output follows,
    /// as during a dark-frame or calibration job).
    pub(super) fn answer_marks(&mut self, published: u64) {
        let (done, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.pending_marks)
            .into_iter()
            .partition(|p| p.captured.is_some_and(|m| m.sequence <= published));
        self.pending_marks = waiting;
        for p in done {
            if let Some(mark) = p.captured {
                let _ = p.reply.send(mark);
            }
        }
    }

    /// While the source delivers nothing, setting changes return at once with
    /// the sequence number the next frame will carry.
    pub(super) fn answer_marks_while_stalled(&mut self) {
        let next = FrameMark {
            sequence: self.sequence + 1,
            timestamp_us: 0,
        };
        for p in std::mem::take(&mut self.pending_marks) {
            let _ = p.reply.send(p.captured.unwrap_or(next));
        }
    }

    pub(super) fn await_first_frame(&mut self, reply: Reply<FrameMark>) {
        self.pending_marks.push(PendingMark {
            reply,
            captured: None,
        });
    }
}
