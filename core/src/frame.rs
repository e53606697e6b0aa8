//! One sensor readout: signed difference values in DN plus per-pixel flags.

use crate::image::Image;

/// A difference frame as delivered by a sensor (simulated or real), in DN,
/// with the ADC offset already removed: positive where LS1 (I+) dominates.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Signed difference, DN (eq. pixeleff after quantization).
    pub dn: Image<f32>,
    /// Non-zero where a well reached full-well capacity or the ADC clipped.
    pub saturated: Image<u8>,
    /// Start of the exposure, microseconds on the sensor's clock.
    pub timestamp_us: u64,
    /// Frame counter: as issued by the sensor, renumbered by sdid (one per
    /// capture since start, never reset; see `FrameMark` in the daemon).
    pub sequence: u64,
}

impl Frame {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            dn: Image::new(width, height),
            saturated: Image::new(width, height),
            timestamp_us: 0,
            sequence: 0,
        }
    }

    pub fn width(&self) -> usize {
        self.dn.width
    }

    pub fn height(&self) -> usize {
        self.dn.height
    }

    /// Number of pixels flagged as saturated.
    pub fn saturated_count(&self) -> usize {
        self.saturated.data.iter().filter(|&&s| s != 0).count()
    }
}
