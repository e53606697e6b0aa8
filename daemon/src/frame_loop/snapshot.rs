//! Snapshots: the latest output, answered at once or, while the lights
//! are off or settling, once two consecutive lit captures are in.

use std::sync::Arc;

use sdi_core::display::DisplayMap;
use sdi_core::mode::{ModeId, ModeOutput};

use super::FrameLoop;

/// The latest processed frame, for snapshots.
pub struct SnapshotData {
    pub mode: ModeId,
    pub output: Arc<ModeOutput>,
    pub display: DisplayMap,
}

impl FrameLoop {
    /// The latest output, with the mode and display it was made for.
    pub(super) fn snapshot(&self) -> Option<SnapshotData> {
        self.last.clone().map(|output| SnapshotData {
            mode: self.mode,
            output,
            display: self.display,
        })
    }

    /// Answers every snapshot waiting for lit frames with the latest output.
    pub(super) fn answer_pending_snapshots(&mut self) {
        for reply in std::mem::take(&mut self.pending_snapshots) {
            let _ = reply.send(self.snapshot());
        }
    }
}
