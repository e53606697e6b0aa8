//! What a mode pipeline produces per output frame.

use crate::image::Image;
use crate::separation::Separated;

/// One output image of a mode.
#[derive(Debug, Clone, PartialEq)]
pub struct ModeOutput {
    /// Signed difference, DN: positive where LS1 (I+) dominates.
    pub signed_dn: Image<f32>,
    /// [`PixelFlags`](crate::PixelFlags) bits per pixel (SATURATED, NONFINITE); 0 = valid.
    pub flags: Image<u8>,
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
    /// One-sigma standard errors of I+ and I- from the moments' sampling
    /// (co)variances (`separation::unmix`), electrons.
    pub i_plus_se_electrons: Image<f32>,
    pub i_minus_se_electrons: Image<f32>,
}

impl ModeOutput {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            signed_dn: Image::new(width, height),
            flags: Image::new(width, height),
            timestamp_us: 0,
            sequence: 0,
            channels: None,
        }
    }

    /// Stamps a signed image without channels (a spare from the separation
    /// mode may carry some) with its capture time and sequence number.
    pub(crate) fn stamp_image(&mut self, timestamp_us: u64, sequence: u64) {
        self.timestamp_us = timestamp_us;
        self.sequence = sequence;
        self.channels = None;
    }

    /// Reallocates only when the size changes (warm-up); the channels'
    /// buffers are kept for [`SeparatedChannels::assign`].
    pub(crate) fn ensure_size(&mut self, width: usize, height: usize) {
        if self.signed_dn.width != width || self.signed_dn.height != height {
            *self = Self::new(width, height);
        }
    }
}

impl SeparatedChannels {
    /// `slot` set to a copy of `separated`'s channels, into the buffers it
    /// already holds when their size fits (no allocation once sizes settle).
    pub(crate) fn assign(slot: &mut Option<Self>, separated: &Separated) {
        let src = [
            &separated.i_plus_electrons,
            &separated.i_minus_electrons,
            &separated.i_plus_se_electrons,
            &separated.i_minus_se_electrons,
        ];
        match slot {
            Some(ch) if src.iter().all(|s| s.same_size(&ch.i_plus_electrons)) => {
                let dst = [
                    &mut ch.i_plus_electrons,
                    &mut ch.i_minus_electrons,
                    &mut ch.i_plus_se_electrons,
                    &mut ch.i_minus_se_electrons,
                ];
                for (d, s) in dst.into_iter().zip(src) {
                    d.data.copy_from_slice(&s.data);
                }
            }
            _ => {
                *slot = Some(Self {
                    i_plus_electrons: separated.i_plus_electrons.clone(),
                    i_minus_electrons: separated.i_minus_electrons.clone(),
                    i_plus_se_electrons: separated.i_plus_se_electrons.clone(),
                    i_minus_se_electrons: separated.i_minus_se_electrons.clone(),
                });
            }
        }
    }
}
