//! Where each processed frame goes from the frame loop, in one place: every
//! sink (each on its own thread behind its own queue), every client's frame
//! stream, and the latest frame, kept for snapshots. The recorder is not
//! here: it records the sensor's frames, before the mode pipeline.

use std::sync::Arc;

use sdi_core::mode::ModeOutput;

use crate::frame_stream::FrameStreams;
use crate::out_frame::OutFrame;
use crate::sink::output::Output;

pub struct Fanout {
    sinks: Output,
    streams: FrameStreams,
    latest: Option<Arc<OutFrame>>,
    /// The output of an earlier frame every consumer is done with, for the
    /// pipeline to write a later one into.
    spare: Option<ModeOutput>,
}

impl Fanout {
    pub fn new(sinks: Output) -> Self {
        Self {
            sinks,
            streams: FrameStreams::default(),
            latest: None,
            spare: None,
        }
    }

    /// Hands `frame` to every sink and stream (never blocks) and keeps it
    /// as the latest. The frame it replaces as the latest becomes the spare
    /// when nobody else holds it any more (the sinks had a frame period).
    pub fn publish(&mut self, frame: OutFrame) -> &Arc<OutFrame> {
        let frame = Arc::new(frame);
        self.sinks.send(&frame);
        self.streams.send(&frame);
        if let Some(done) = self.latest.take().and_then(|f| Arc::try_unwrap(f).ok()) {
            self.spare = Some(done.into_output());
        }
        self.latest.insert(frame)
    }

    /// An output no consumer holds any more, to be written over (see
    /// [`sdi_core::mode::Pipeline::take_output`]); None when every recent
    /// one is still held.
    pub fn take_spare(&mut self) -> Option<ModeOutput> {
        self.spare.take()
    }

    /// Queues the "no signal" card, stamped `timestamp_us`, for the sinks
    /// (streams carry frames only).
    pub fn no_signal(&self, timestamp_us: u64) {
        self.sinks.send_no_signal(timestamp_us);
    }

    /// The last frame published, if any.
    pub fn latest(&self) -> Option<&Arc<OutFrame>> {
        self.latest.as_ref()
    }

    /// Readers of the sinks (as they last reported) and of the frame
    /// streams; `None` when a sink cannot tell.
    pub fn watchers(&self) -> Option<u32> {
        self.sinks
            .watchers()
            .map(|n| n.saturating_add(self.streams.len() as u32))
    }

    /// Frames a sink missed because it was busy: the most any one missed.
    pub fn dropped_view(&self) -> u64 {
        self.sinks.dropped()
    }

    pub fn streams(&mut self) -> &mut FrameStreams {
        &mut self.streams
    }
}
