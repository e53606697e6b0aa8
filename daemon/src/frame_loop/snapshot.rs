//! Snapshots: the latest output, answered at once or, while the lights
//! are off or settling, once two consecutive lit captures are in.

use std::sync::Arc;

use super::FrameLoop;
use crate::out_frame::OutFrame;

/// The latest processed frame, for snapshots: the mode and display it
/// was made with travel with it.
pub type SnapshotData = Arc<OutFrame>;

impl FrameLoop {
    /// The latest output.
    pub(super) fn snapshot(&self) -> Option<SnapshotData> {
        self.fanout.latest().cloned()
    }

    /// Answers every snapshot waiting for lit frames with the latest output.
    pub(super) fn answer_pending_snapshots(&mut self) {
        for reply in std::mem::take(&mut self.pending_snapshots) {
            let _ = reply.send(self.snapshot());
        }
    }
}
