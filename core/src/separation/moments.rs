//! Per-pixel sample statistics in DN: the common output of M1, M2 and M3.

use crate::image::Image;

/// Mean and variance of each pixel with their sampling (co)variances.
#[derive(Debug, Clone, PartialEq)]
pub struct Moments {
    pub mean_dn: Image<f64>,
    pub variance_dn2: Image<f64>,
    /// Var of `mean_dn` (squared standard error), DN^2.
    pub mean_var_dn2: Image<f64>,
    /// Var of `variance_dn2`, DN^4.
    pub variance_var_dn4: Image<f64>,
    /// Cov(mean, variance) = mu_3 / n, DN^3 (0 where not estimated).
    pub mean_variance_cov_dn3: Image<f64>,
    /// Number (or effective number) of samples behind each pixel.
    pub samples: Image<f64>,
    /// [`PixelFlags`](crate::PixelFlags) bits.
    pub flags: Image<u8>,
}

impl Moments {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            mean_dn: Image::new(width, height),
            variance_dn2: Image::new(width, height),
            mean_var_dn2: Image::new(width, height),
            variance_var_dn4: Image::new(width, height),
            mean_variance_cov_dn3: Image::new(width, height),
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

    /// Stores one pixel from central moments m2 (variance), m3, m4 of `n`
    /// samples; sampling variances from the standard large-sample formulas
    /// Var(s^2) = (m4 - s^4 (n-3)/(n-1)) / n, Cov(mean, s^2) = m3 / n.
    /// When `m4` is `None` the Gaussian value 2 s^4 / (n-1) is used.
    pub(crate) fn set_from_central(
        &mut self,
        i: usize,
        n: f64,
        mean: f64,
        var: f64,
        m3: f64,
        m4: Option<f64>,
    ) {
        if n < 2.0 || !(mean.is_finite() && var.is_finite()) {
            self.set_insufficient(i);
            return;
        }
        let var = var.max(0.0);
        let gauss = 2.0 * var * var / (n - 1.0);
        let var_var = match m4 {
            Some(m4) if m4.is_finite() => {
                ((m4 - var * var * (n - 3.0) / (n - 1.0)) / n).max(gauss * 0.5)
            }
            _ => gauss,
        };
        self.mean_dn.data[i] = mean;
        self.variance_dn2.data[i] = var;
        self.mean_var_dn2.data[i] = var / n;
        self.variance_var_dn4.data[i] = var_var;
        self.mean_variance_cov_dn3.data[i] = if m3.is_finite() { m3 / n } else { 0.0 };
        self.samples.data[i] = n;
    }

    pub(crate) fn set_insufficient(&mut self, i: usize) {
        self.mean_dn.data[i] = 0.0;
        self.variance_dn2.data[i] = 0.0;
        self.mean_var_dn2.data[i] = f64::INFINITY;
        self.variance_var_dn4.data[i] = f64::INFINITY;
        self.mean_variance_cov_dn3.data[i] = 0.0;
        self.flags.data[i] |= crate::PixelFlags::INSUFFICIENT.bits();
    }
}

/// One pixel's statistics as [`super::unmix`] needs them, DN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelStats {
    pub mean_dn: f64,
    pub variance_dn2: f64,
    pub mean_var_dn2: f64,
    pub variance_var_dn4: f64,
    pub mean_variance_cov_dn3: f64,
}

/// Per-pixel statistics from any estimator ([`Moments`], [`super::LocalMoments`]).
pub trait MomentSource {
    /// Per-pixel [`crate::PixelFlags`] bits, at the estimator's size.
    fn flags(&self) -> &Image<u8>;
    /// (width, height).
    fn size(&self) -> (usize, usize) {
        (self.flags().width, self.flags().height)
    }
    /// Pixel `i`'s statistics; meaningful where INSUFFICIENT is not flagged.
    fn pixel(&self, i: usize) -> PixelStats;
}

impl MomentSource for Moments {
    fn flags(&self) -> &Image<u8> {
        &self.flags
    }

    #[inline]
    fn pixel(&self, i: usize) -> PixelStats {
        PixelStats {
            mean_dn: self.mean_dn.data[i],
            variance_dn2: self.variance_dn2.data[i],
            mean_var_dn2: self.mean_var_dn2.data[i],
            variance_var_dn4: self.variance_var_dn4.data[i],
            mean_variance_cov_dn3: self.mean_variance_cov_dn3.data[i],
        }
    }
}
