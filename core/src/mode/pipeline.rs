//! The mode pipeline: sensor frames in, signed float DN out.
//!
//! Each mode is a short chain of small stages and runs only those it needs:
//!
//! | mode | stages |
//! | --- | --- |
//! | raw, direct-only, bipolar-colour, depth-edge(-vertical), spatial-gradient, temporal-gradient | copy -> dark subtraction (only when a dark frame is set) -> invalid-pixel handling |
//! | two-shot | pairing (A = LS1 frame, B = LS2 frame) -> digital subtraction A - B -> invalid-pixel handling |
//! | separation | as the snapshot modes, plus dark-subtracted frame -> [`crate::separation::LiveSeparator`] (M3, or M1 over a window) -> I+, I- in electrons |
//!
//! In the snapshot modes the difference is formed in the pixel, before the
//! ADC (eq. pixeleff); what differs between them is the optics and the
//! illumination ([`ModeId::illumination`]), not the arithmetic. Display
//! mapping is not a pipeline stage: sinks call [`crate::display::DisplayMap`].
//! After the first frame (or a change of frame size) no stage allocates.

use super::separation::{SeparationConfig, SeparationPipeline};
use super::snapshot::SnapshotPipeline;
use super::two_shot::TwoShotPipeline;
use super::ModeId;
use crate::frame::Frame;
use crate::image::Image;

/// Per-pixel flags of [`ModeOutput::saturated`] (bit set).
pub mod flags {
    /// A well reached full-well capacity or the ADC clipped.
    pub const SATURATED: u8 = 1;
    /// The input was NaN or infinite; the output value is 0.
    pub const INVALID: u8 = 2;
}

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
    pub separation: SeparationConfig,
}

/// One output image of a mode.
#[derive(Debug, Clone, PartialEq)]
pub struct ModeOutput {
    /// Signed difference, DN: positive where LS1 (I+) dominates.
    pub signed_dn: Image<f32>,
    /// Bit flags per pixel, see [`flags`]; 0 = valid.
    pub saturated: Image<u8>,
    /// Start of the (first) exposure that produced this output, microseconds.
    pub timestamp_us: u64,
    /// Sequence number of the (last) frame that completed this output.
    pub sequence: u64,
    /// I+ and I- of the separation mode; None in every other mode (and while
    /// a sliding window fills).
    pub channels: Option<SeparatedChannels>,
}

/// The two latent images recovered by the separation mode (section 6).
#[derive(Debug, Clone, PartialEq)]
pub struct SeparatedChannels {
    /// I+ (LS1), electrons per exposure.
    pub i_plus_electrons: Image<f32>,
    /// I- (LS2), electrons per exposure.
    pub i_minus_electrons: Image<f32>,
}

impl ModeOutput {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            signed_dn: Image::new(width, height),
            saturated: Image::new(width, height),
            timestamp_us: 0,
            sequence: 0,
            channels: None,
        }
    }

    /// Reallocates only when the size changes (warm-up).
    pub(crate) fn ensure_size(&mut self, width: usize, height: usize) {
        if self.signed_dn.width != width || self.signed_dn.height != height {
            *self = Self::new(width, height);
        }
    }
}

/// A running mode: feed frames, get output images.
pub trait Pipeline: Send {
    fn mode(&self) -> ModeId;
    /// Feeds one sensor frame; Some when an output frame is ready (two-shot may need a pair).
    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput>;
    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>);
    /// Whether this pipeline will subtract the dark frame it holds from frames
    /// of this size (false when none is set, it does not fit, or the mode
    /// does not need one).
    fn dark_frame_applies(&self, width: usize, height: usize) -> bool;
    /// Forgets state carried between frames (a half-formed two-shot pair).
    fn reset(&mut self) {}
}

/// The pipeline of `mode`.
pub fn build_pipeline(mode: ModeId, config: PipelineConfig) -> Box<dyn Pipeline> {
    match mode {
        ModeId::TwoShot => Box::new(TwoShotPipeline::new(config)),
        ModeId::Separation => Box::new(SeparationPipeline::new(config)),
        ModeId::Raw
        | ModeId::DirectOnly
        | ModeId::BipolarColour
        | ModeId::DepthEdge
        | ModeId::DepthEdgeVertical
        | ModeId::SpatialGradient
        | ModeId::TemporalGradient => Box::new(SnapshotPipeline::new(mode, config)),
    }
}
