//! The two-shot baseline (section 5.3 and 5.5): LS1 alone in one frame, LS2
//! alone in the next, subtracted digitally after the ADC.
//!
//! Pairing: frames are paired by sensor sequence number, matching
//! [`ModeId::illumination`]: an even frame A (LS1) followed by the odd frame
//! B = A + 1 (LS2) yields one output A - B, emitted when B arrives; so the
//! output rate is half the frame rate. A frame without its partner (a dropped
//! frame, or the stream starting on an odd frame) is discarded rather than
//! paired with the wrong sign.
//!
//! Costs against the snapshot modes (eq. pre_post_noise): each of the two
//! readouts carries its own read noise, so the read-noise variance counts
//! twice (at low light the variance is twice the snapshot's); and anything
//! that moves between the two exposures leaves a ghost, positive where it was
//! in A and negative where it is in B. The dark frame needs no subtraction:
//! it cancels exactly in A - B.

use super::invalid_pixels::handle_invalid;
use super::output::ModeOutput;
use super::pipeline::{Pipeline, PipelineConfig};
use super::ModeId;
use crate::frame::Frame;
use crate::image::Image;

pub struct TwoShotPipeline {
    config: PipelineConfig,
    /// The held LS1 frame A, waiting for its partner.
    first: Frame,
    first_pending: bool,
    /// Saturation flags of A OR B.
    saturated_either: Vec<u8>,
    out: ModeOutput,
}

impl TwoShotPipeline {
    pub fn new(config: PipelineConfig) -> Self {
        Self {
            config,
            first: Frame::new(0, 0),
            first_pending: false,
            saturated_either: Vec::new(),
            out: ModeOutput::new(0, 0),
        }
    }

    /// Whether frame `sequence` is an LS1 (A) frame.
    pub fn is_first_of_pair(sequence: u64) -> bool {
        sequence & 1 == 0
    }

    fn hold(&mut self, frame: &Frame) {
        if !self.first.dn.same_size(&frame.dn) {
            self.first = frame.clone();
        } else {
            self.first.dn.data.copy_from_slice(&frame.dn.data);
            self.first
                .saturated
                .data
                .copy_from_slice(&frame.saturated.data);
            self.first.timestamp_us = frame.timestamp_us;
            self.first.sequence = frame.sequence;
        }
        self.first_pending = true;
    }
}

impl Pipeline for TwoShotPipeline {
    fn mode(&self) -> ModeId {
        ModeId::TwoShot
    }

    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput> {
        if Self::is_first_of_pair(frame.sequence) {
            self.hold(frame);
            return None;
        }
        let partner = self.first_pending
            && self.first.dn.same_size(&frame.dn)
            && self.first.sequence.checked_add(1) == Some(frame.sequence);
        self.first_pending = false;
        if !partner {
            return None;
        }
        let (w, h) = (frame.width(), frame.height());
        self.out.ensure_size(w, h);
        self.saturated_either.resize(w * h, 0);
        let out = &mut self.out;
        let a = self.first.dn.data.iter().zip(&self.first.saturated.data);
        let b = frame.dn.data.iter().zip(&frame.saturated.data);
        let dst = out
            .signed_dn
            .data
            .iter_mut()
            .zip(self.saturated_either.iter_mut());
        for ((d, s), ((&va, &sa), (&vb, &sb))) in dst.zip(a.zip(b)) {
            *d = va - vb;
            *s = sa | sb;
        }
        handle_invalid(
            &mut out.signed_dn.data,
            &self.saturated_either,
            &mut out.flags.data,
            self.config.zero_saturated,
        );
        out.stamp_image(self.first.timestamp_us, frame.sequence);
        Some(&self.out)
    }

    fn take_output(&mut self, spare: ModeOutput) -> ModeOutput {
        std::mem::replace(&mut self.out, spare)
    }

    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>) {
        // Kept for reporting only: (A - dark) - (B - dark) = A - B.
        self.config.dark_frame_dn = dark_dn;
    }

    fn dark_frame_applies(&self, _width: usize, _height: usize) -> bool {
        false
    }

    fn reset(&mut self) {
        self.first_pending = false;
    }
}
