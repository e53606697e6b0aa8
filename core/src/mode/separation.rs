//! The live separation mode (section 6): the signed difference as in the
//! snapshot modes, plus I+ and I- recovered on every frame by
//! [`LiveSeparator`] (M3 per frame by default, or M1 over a sliding window).
//!
//! Only this mode runs the estimator; the separation reads the dark-subtracted
//! frame (the dark offset would bias the mean, eq. skellammatrix's mu), with
//! saturated and non-finite pixels flagged by the estimator itself.

use super::output::{ModeOutput, SeparatedChannels};
use super::pipeline::{Pipeline, PipelineConfig};
use super::snapshot::SnapshotPipeline;
use super::ModeId;
use crate::dark_frame::subtract_dark;
use crate::frame::Frame;
use crate::image::Image;
use crate::separation::LiveSeparator;

pub struct SeparationPipeline {
    signed: SnapshotPipeline,
    separator: LiveSeparator,
    /// The frame the estimator sees when a dark frame applies: the input,
    /// dark-subtracted.
    scratch: Frame,
    out: ModeOutput,
}

impl SeparationPipeline {
    pub fn new(config: PipelineConfig) -> Self {
        let sep = config.separation;
        Self {
            signed: SnapshotPipeline::new(ModeId::Separation, config),
            separator: LiveSeparator::from_config(sep),
            scratch: Frame::new(0, 0),
            out: ModeOutput::new(0, 0),
        }
    }
}

/// The frame the estimator reads: `frame` itself, or with `dark` fitting
/// it, a dark-subtracted copy in `scratch` (reallocated only on a size change).
fn dark_subtracted<'a>(
    scratch: &'a mut Frame,
    frame: &'a Frame,
    dark: Option<&Image<f32>>,
) -> &'a Frame {
    let Some(d) = dark.filter(|d| d.same_size(&frame.dn)) else {
        return frame;
    };
    if !scratch.dn.same_size(&frame.dn) {
        *scratch = frame.clone();
    } else {
        scratch.dn.data.copy_from_slice(&frame.dn.data);
        scratch
            .saturated
            .data
            .copy_from_slice(&frame.saturated.data);
        scratch.timestamp_us = frame.timestamp_us;
        scratch.sequence = frame.sequence;
    }
    subtract_dark(&mut scratch.dn.data, &d.data);
    scratch
}

impl Pipeline for SeparationPipeline {
    fn mode(&self) -> ModeId {
        ModeId::Separation
    }

    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput> {
        self.signed.process(frame)?;
        // The signed image and flags are the snapshot pipeline's output,
        // handed over; our previous one (its channels kept) goes back to it.
        let mut channels = self.out.channels.take();
        let spare = std::mem::replace(&mut self.out, ModeOutput::new(0, 0));
        self.out = self.signed.take_output(spare);
        let input = dark_subtracted(&mut self.scratch, frame, self.signed.dark_frame());
        match self.separator.process(input) {
            Ok(Some(s)) => SeparatedChannels::assign(&mut channels, s),
            // A sliding window still filling up: the signed image alone.
            // core does not log: on an estimator error (e.g. an empty
            // frame) the output carries the signed image alone.
            Ok(None) | Err(_) => channels = None,
        }
        self.out.channels = channels;
        Some(&self.out)
    }

    fn take_output(&mut self, spare: ModeOutput) -> ModeOutput {
        std::mem::replace(&mut self.out, spare)
    }

    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>) {
        self.signed.set_dark_frame(dark_dn);
    }

    fn dark_frame_applies(&self, width: usize, height: usize) -> bool {
        self.signed.dark_frame_applies(width, height)
    }

    fn reset(&mut self) {
        self.signed.reset();
    }
}
