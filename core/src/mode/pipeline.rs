//! The mode pipeline: sensor frames in, signed float DN out.
//!
//! Each mode runs one of three short chains of small stages, named by its
//! [`super::ModeSpec::pipeline`]:
//!
//! | pipeline | stages |
//! | --- | --- |
//! | snapshot | copy -> dark subtraction (only when a dark frame is set) -> invalid-pixel handling |
//! | two-shot | pairing (A = LS1 frame, B = LS2 frame) -> digital subtraction A - B -> invalid-pixel handling |
//! | separation | as snapshot, plus dark-subtracted frame -> [`crate::separation::LiveSeparator`] (M3, or M1 over a window) -> I+, I- in electrons |
//!
//! In the snapshot modes the difference is formed in the pixel, before the
//! ADC (eq. pixeleff); what differs between them is the optics and the
//! illumination ([`ModeId::illumination`]), not the arithmetic. Display
//! mapping is not a pipeline stage: sinks call [`crate::display::DisplayMap`].
//! After the first frame (or a change of frame size) no stage allocates.

use super::output::ModeOutput;
use super::ModeId;
use crate::frame::Frame;
use crate::image::Image;
use crate::separation::LiveSeparatorConfig;

/// How a pipeline is set up.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PipelineConfig {
    /// Mean dark frame, DN, subtracted from each frame (section 4). A dark
    /// frame whose size differs from the frames is not applied.
    pub dark_frame_dn: Option<Image<f32>>,
    /// Replace saturated pixels by 0 DN instead of keeping their clipped value
    /// (they stay flagged either way).
    pub zero_saturated: bool,
    /// Estimator and H of the separation mode (ignored by the other modes).
    pub separation: LiveSeparatorConfig,
}

/// A running mode: feed frames, get output images.
pub trait Pipeline: Send {
    fn mode(&self) -> ModeId;
    /// Feeds one sensor frame; Some when an output frame is ready (two-shot may need a pair).
    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput>;
    /// Hands over the output the last [`Self::process`] returned and keeps
    /// `spare` (an earlier output given back, or an empty one) to write the
    /// next into: a caller that keeps the output owns it without a copy.
    fn take_output(&mut self, spare: ModeOutput) -> ModeOutput;
    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>);
    /// Whether this pipeline will subtract the dark frame it holds from frames
    /// of this size (false when none is set, it does not fit, or the mode
    /// does not need one).
    fn dark_frame_applies(&self, width: usize, height: usize) -> bool;
    /// Forgets state carried between frames (a half-formed two-shot pair).
    fn reset(&mut self) {}
}
