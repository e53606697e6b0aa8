//! Beyond the paper: M1 followed by edge-aware spatial pooling of the
//! per-pixel moments.
//!
//! After N frames the mean image is precise (standard error sigma/sqrt(N))
//! but the sample variance is not (relative standard error sqrt(2/(N-1)),
//! 4.5% at N = 1000), and that noise dominates I+ and I- (section 6:
//! (I+, I-) = H^-1 (mu, sigma^2 - sigma_read^2)). Each pixel therefore
//! averages the moments of the neighbours in a (2r+1)^2 window whose mean
//! AND variance agree with its own within `tolerance_sigmas` of their joint
//! standard errors, i.e. that are statistically the same surface. The mean
//! keeps the guide's edges; the standard errors shrink by the number pooled.
//! It assumes I+ and I- are locally constant where the statistics agree (a
//! smooth gradient inside the window biases the result slightly).

use super::{Moments, SeparationError};
use crate::PixelFlags;

/// Parameters of [`pool_moments`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoolParams {
    /// Window half-width, px.
    pub radius_px: usize,
    /// Neighbours whose mean and variance differ by more than this many
    /// joint standard errors are left out.
    pub tolerance_sigmas: f64,
}

impl Default for PoolParams {
    fn default() -> Self {
        Self {
            radius_px: 4,
            tolerance_sigmas: 3.0,
        }
    }
}

/// Edge-aware pooling of per-pixel moments (see module docs). Pixels flagged
/// [`PixelFlags::INSUFFICIENT`] are neither pooled nor used.
pub fn pool_moments(m: &Moments, params: PoolParams) -> Result<Moments, SeparationError> {
    let t = params.tolerance_sigmas;
    SeparationError::check("tolerance_sigmas", t, t > 0.0, "> 0")?;
    let (w, h) = (m.width(), m.height());
    if w * h == 0 {
        return Err(SeparationError::Empty);
    }
    // A window wider than the image covers the same pixels as one exactly as
    // wide; clamping keeps `x + r + 1` from overflowing (radius usize::MAX).
    let r = params.radius_px.min(w.max(h));
    let t2 = t * t;
    let ok = |i: usize| m.flags.data[i] & PixelFlags::INSUFFICIENT.bits() == 0;
    let mut out = m.clone();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !ok(i) {
                continue;
            }
            let (mu, v) = (m.mean_dn.data[i], m.variance_dn2.data[i]);
            let (smv, svv) = (m.mean_var_dn2.data[i], m.variance_var_dn4.data[i]);
            let mut k = 0.0f64;
            let mut acc = [0.0f64; 6];
            let mut f = 0u8;
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    let j = yy * w + xx;
                    if !ok(j) {
                        continue;
                    }
                    let dm = m.mean_dn.data[j] - mu;
                    let dv = m.variance_dn2.data[j] - v;
                    if dm * dm > t2 * (smv + m.mean_var_dn2.data[j])
                        || dv * dv > t2 * (svv + m.variance_var_dn4.data[j])
                    {
                        continue;
                    }
                    k += 1.0;
                    acc[0] += m.mean_dn.data[j];
                    acc[1] += m.variance_dn2.data[j];
                    acc[2] += m.mean_var_dn2.data[j];
                    acc[3] += m.variance_var_dn4.data[j];
                    acc[4] += m.mean_variance_cov_dn3.data[j];
                    acc[5] += m.samples.data[j];
                    f |= m.flags.data[j];
                }
            }
            // k >= 1: the pixel always agrees with itself.
            out.mean_dn.data[i] = acc[0] / k;
            out.variance_dn2.data[i] = acc[1] / k;
            out.mean_var_dn2.data[i] = acc[2] / (k * k);
            out.variance_var_dn4.data[i] = acc[3] / (k * k);
            out.mean_variance_cov_dn3.data[i] = acc[4] / (k * k);
            out.samples.data[i] = acc[5];
            out.flags.data[i] |= f & (PixelFlags::SATURATED.bits() | PixelFlags::NONFINITE.bits());
        }
    }
    Ok(out)
}
