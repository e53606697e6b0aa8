//! Per-pixel quality flags, one bit set shared by the mode pipelines and the
//! estimators. Images store the bits as `u8` ([`PixelFlags::bits`]).

bitflags::bitflags! {
    /// Why a pixel's value is missing, clamped or to be read with care.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
    pub struct PixelFlags: u8 {
        /// A well reached full-well capacity or the ADC clipped (estimators:
        /// at least one saturated sample was kept out of this pixel's statistics).
        const SATURATED = 1 << 0;
        /// A NaN or infinite sample was masked out (pipelines: the output value is 0).
        const NONFINITE = 1 << 1;
        /// Sample variance fell below the read-noise variance and was clamped to it.
        const VARIANCE_CLAMPED = 1 << 2;
        /// Fewer than two usable samples: no variance; outputs are 0 with infinite error.
        const INSUFFICIENT = 1 << 3;
        /// The unconstrained estimate had a negative intensity and was projected onto I+, I- >= 0.
        const PROJECTED = 1 << 4;
    }
}

#[cfg(test)]
mod tests {
    use super::PixelFlags;

    #[test]
    fn bits_are_the_stored_values() {
        // recordings and `sdictl separate --flags` files carry these numbers
        assert_eq!(PixelFlags::SATURATED.bits(), 1);
        assert_eq!(PixelFlags::NONFINITE.bits(), 2);
        assert_eq!(PixelFlags::VARIANCE_CLAMPED.bits(), 4);
        assert_eq!(PixelFlags::INSUFFICIENT.bits(), 8);
        assert_eq!(PixelFlags::PROJECTED.bits(), 16);
    }
}
