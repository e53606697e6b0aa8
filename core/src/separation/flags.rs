//! Per-pixel quality flags (bit set in a `u8`), shared by all estimators.

/// At least one saturated sample was kept out of this pixel's statistics
/// (or, for single-frame estimators, the pixel itself is saturated).
pub const SATURATED: u8 = 1 << 0;
/// A NaN or infinite sample was masked out.
pub const NONFINITE: u8 = 1 << 1;
/// Sample variance fell below the read-noise variance and was clamped to it.
pub const VARIANCE_CLAMPED: u8 = 1 << 2;
/// Fewer than two usable samples: no variance; outputs are 0 with infinite error.
pub const INSUFFICIENT: u8 = 1 << 3;
/// The unconstrained estimate had a negative intensity and was projected onto I+, I- >= 0.
pub const PROJECTED: u8 = 1 << 4;
