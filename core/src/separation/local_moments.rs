//! Per-pixel weighted statistics of one frame, f32: the light output of the
//! fast M3 variants (one frame in, every frame), three images and flags
//! instead of [`Moments`]' six f64 images.

use super::{MomentSource, Moments, PixelStats};
use crate::image::Image;
use crate::PixelFlags;

/// Weighted mean and variance of each pixel's neighbourhood, DN, with the
/// effective number of samples (sum w)^2 / sum w^2 behind them. Sampling
/// variances follow from these under the Gaussian approximation:
/// Var(mean) = var / n, Var(var) = 2 var^2 / (n - 1), Cov = 0.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LocalMoments {
    pub mean_dn: Image<f32>,
    pub variance_dn2: Image<f32>,
    pub samples: Image<f32>,
    /// [`PixelFlags`](crate::PixelFlags) bits; INSUFFICIENT pixels carry mean 0 and variance 0.
    pub flags: Image<u8>,
}

impl LocalMoments {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            mean_dn: Image::new(width, height),
            variance_dn2: Image::new(width, height),
            samples: Image::new(width, height),
            flags: Image::new(width, height),
        }
    }

    pub fn width(&self) -> usize {
        self.mean_dn.width
    }

    pub fn height(&self) -> usize {
        self.mean_dn.height
    }

    /// Resizes (contents unspecified) unless already `width x height`.
    pub(crate) fn ensure_size(&mut self, width: usize, height: usize) {
        if self.width() != width || self.height() != height {
            *self = Self::new(width, height);
        }
    }

    /// Marks pixel `i` as having no statistics (fewer than two effective
    /// samples, `samples` of them).
    #[inline]
    pub(crate) fn set_insufficient(&mut self, i: usize, samples: f32) {
        self.mean_dn.data[i] = 0.0;
        self.variance_dn2.data[i] = 0.0;
        self.samples.data[i] = samples;
        self.flags.data[i] |= PixelFlags::INSUFFICIENT.bits();
    }

    /// The same statistics as full [`Moments`] (f64, sampling variances spelt out).
    pub fn to_moments(&self) -> Moments {
        let (w, h) = (self.width(), self.height());
        let mut out = Moments::new(w, h);
        for i in 0..w * h {
            out.flags.data[i] = self.flags.data[i];
            let n = self.samples.data[i] as f64;
            if self.flags.data[i] & PixelFlags::INSUFFICIENT.bits() != 0 {
                out.set_insufficient(i);
                out.samples.data[i] = n;
                continue;
            }
            let (mean, var) = (
                self.mean_dn.data[i] as f64,
                self.variance_dn2.data[i] as f64,
            );
            out.set_from_central(i, n, mean, var, 0.0, None);
        }
        out
    }
}

impl MomentSource for LocalMoments {
    fn flags(&self) -> &Image<u8> {
        &self.flags
    }

    /// Gaussian sampling variances (see the type's docs); producers flag
    /// INSUFFICIENT wherever `samples` < 2.
    #[inline]
    fn pixel(&self, i: usize) -> PixelStats {
        let n = self.samples.data[i] as f64;
        let var = self.variance_dn2.data[i] as f64;
        PixelStats {
            mean_dn: self.mean_dn.data[i] as f64,
            variance_dn2: var,
            mean_var_dn2: var / n,
            variance_var_dn4: 2.0 * var * var / (n - 1.0),
            mean_variance_cov_dn3: 0.0,
        }
    }
}
