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
    /// The frame the estimator sees: dark-subtracted copy of the input.
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

/// Copies `frame` into `scratch` (reallocating only on a size change) and
/// subtracts `dark` when it fits.
fn fill_scratch(scratch: &mut Frame, frame: &Frame, dark: Option<&Image<f32>>) {
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
    if let Some(d) = dark.filter(|d| d.same_size(&frame.dn)) {
        subtract_dark(&mut scratch.dn.data, &d.data);
    }
}

impl Pipeline for SeparationPipeline {
    fn mode(&self) -> ModeId {
        ModeId::Separation
    }

    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput> {
        let signed = self.signed.process(frame)?;
        let out = &mut self.out;
        out.ensure_size(frame.width(), frame.height());
        out.signed_dn.data.copy_from_slice(&signed.signed_dn.data);
        out.flags.data.copy_from_slice(&signed.flags.data);
        out.timestamp_us = signed.timestamp_us;
        out.sequence = signed.sequence;
        fill_scratch(&mut self.scratch, frame, self.signed.dark_frame());
        out.channels = match self.separator.process(&self.scratch) {
            Ok(Some(s)) => Some(SeparatedChannels {
                i_plus_electrons: s.i_plus_electrons.clone(),
                i_minus_electrons: s.i_minus_electrons.clone(),
                i_plus_se_electrons: s.i_plus_se_electrons.clone(),
                i_minus_se_electrons: s.i_minus_se_electrons.clone(),
            }),
            // A sliding window still filling up: the signed image alone.
            Ok(None) => None,
            // core does not log: on an estimator error (e.g. an empty
            // frame) the output carries the signed image alone.
            Err(_) => None,
        };
        Some(&self.out)
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
