//! Recovering I+ and I- from difference images (paper section 6).
//!
//! Every estimator reduces frames to per-pixel [`Moments`] (mean, variance
//! and their sampling variances, in DN); [`unmix`] then applies
//! (I+, I-) = H^-1 (mu, sigma^2 - sigma_read^2) (eq. skellammatrix) with
//! standard errors, flags and an optional non-negative projection.
//!
//! - M1 [`Welford`]: statistics over N frames, streaming, f64.
//! - M2 [`segment_moments`]: statistics over segments of one frame; [`auto_segment`]
//!   finds the segments.
//! - M3 [`bilateral_exact`], the fast [`BilateralGrid`] (O(1) per pixel) and
//!   [`SeparableBilateral`] (O(r) per pixel, vectorized): bilateral-weighted
//!   statistics of one frame; the fast ones give the light [`LocalMoments`].
//! - Beyond the paper, [`pool_moments`]: M1 followed by edge-aware pooling of
//!   the per-pixel moments.
//! - Beyond the paper, [`skellam_ml_pixel`]: per-pixel Skellam maximum
//!   likelihood (scaled Bessel functions), non-negative by construction.
//! - [`LiveSeparator`]: per-frame separation for the daemon; [`BatchSeparator`]:
//!   a stack by any one estimator, for `sdictl separate` and Python.

use crate::PixelFlags;

mod batch;
mod bessel;
mod bilateral;
mod bilateral_grid;
mod bilateral_separable;
mod error;
mod fast_exp;
mod live;
mod local_moments;
mod moments;
mod pooling;
mod segments;
mod skellam_ml;
mod unmix;
mod welford;

pub use batch::{
    sanitize, BatchError, BatchMethod, BatchParams, BatchSeparator, DEFAULT_ML_WINDOW,
    MAX_BATCH_WINDOW,
};
pub use bessel::ln_bessel_i_scaled;
pub use bilateral::{bilateral_exact, BilateralParams};
pub use bilateral_grid::{bilateral_grid, BilateralGrid, MAX_LEVELS};
pub use bilateral_separable::{bilateral_separable, SeparableBilateral};
pub use error::SeparationError;
pub use live::{
    LiveMethod, LiveSeparator, LiveSeparatorConfig, DEFAULT_BILATERAL, MAX_LIVE_WINDOW_FRAMES,
};
pub use local_moments::LocalMoments;
pub use moments::{MomentSource, Moments, PixelStats};
pub use pooling::{pool_moments, PoolParams};
pub use segments::{
    auto_segment, label_from_f32, noise_sigma, segment_moments, SegmentParams, Segmentation,
    IGNORE_LABEL,
};
pub use skellam_ml::{
    skellam_log_likelihood, skellam_ml_counts, skellam_ml_pixel, MlMethod, SkellamFit,
    COUNTS_READ_NOISE_ELECTRONS,
};
pub use unmix::{unmix, unmix_into, unmix_local_into, Separated, UnmixOptions};
pub use welford::{SlidingWelford, Welford};

/// True when the sample at `i` of `frame` may enter the statistics.
#[inline]
pub(crate) fn usable(frame: &crate::Frame, i: usize) -> bool {
    frame.saturated.data[i] == 0 && frame.dn.data[i].is_finite()
}

/// SATURATED and/or NONFINITE for the input sample at `i`.
#[inline]
pub(crate) fn input_flags(frame: &crate::Frame, i: usize) -> u8 {
    let mut f = 0;
    if frame.saturated.data[i] != 0 {
        f |= PixelFlags::SATURATED.bits();
    }
    if !frame.dn.data[i].is_finite() {
        f |= PixelFlags::NONFINITE.bits();
    }
    f
}
