//! Pipeline of the single-frame (snapshot) modes: the sensor already formed
//! the difference before the ADC (eq. pixeleff); we only remove the dark frame
//! and neutralize invalid pixels.

use super::invalid_pixels::handle_invalid;
use super::output::ModeOutput;
use super::pipeline::{Pipeline, PipelineConfig};
use super::ModeId;
use crate::dark_frame::subtract_dark;
use crate::frame::Frame;
use crate::image::Image;

pub struct SnapshotPipeline {
    mode: ModeId,
    config: PipelineConfig,
    out: ModeOutput,
}

impl SnapshotPipeline {
    pub fn new(mode: ModeId, config: PipelineConfig) -> Self {
        Self {
            mode,
            config,
            out: ModeOutput::new(0, 0),
        }
    }
}

impl SnapshotPipeline {
    /// The dark frame this pipeline holds, if any.
    pub fn dark_frame(&self) -> Option<&Image<f32>> {
        self.config.dark_frame_dn.as_ref()
    }
}

impl Pipeline for SnapshotPipeline {
    fn mode(&self) -> ModeId {
        self.mode
    }

    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput> {
        let (w, h) = (frame.width(), frame.height());
        self.out.ensure_size(w, h);
        let out = &mut self.out;
        out.signed_dn.data.copy_from_slice(&frame.dn.data);
        if let Some(dark) = self.config.dark_frame_dn.as_ref() {
            if dark.width == w && dark.height == h {
                subtract_dark(&mut out.signed_dn.data, &dark.data);
            }
        }
        handle_invalid(
            &mut out.signed_dn.data,
            &frame.saturated.data,
            &mut out.flags.data,
            self.config.zero_saturated,
        );
        out.stamp_image(frame.timestamp_us, frame.sequence);
        Some(&self.out)
    }

    fn take_output(&mut self, spare: ModeOutput) -> ModeOutput {
        std::mem::replace(&mut self.out, spare)
    }

    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>) {
        self.config.dark_frame_dn = dark_dn;
    }

    fn dark_frame_applies(&self, width: usize, height: usize) -> bool {
        self.config
            .dark_frame_dn
            .as_ref()
            .is_some_and(|d| d.width == width && d.height == height)
    }
}
