//! H^-1 applied per pixel (section 6), with standard errors, clamping and an
//! optional projection onto I+, I- >= 0.

use super::{flags, Moments, SeparationError};
use crate::image::Image;
use crate::sensor::SkellamMixing;

/// How to invert H.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnmixOptions {
    /// Subtract sigma_read^2 before inverting (the paper's Fig. pol compares both).
    pub subtract_read_noise: bool,
    /// Never return negative intensities: weighted least squares on the boundary.
    pub nonnegative: bool,
}

impl Default for UnmixOptions {
    fn default() -> Self {
        Self {
            subtract_read_noise: true,
            nonnegative: false,
        }
    }
}

/// The two recovered latent images, electrons, with one-sigma standard errors.
#[derive(Debug, Clone, PartialEq)]
pub struct Separated {
    pub i_plus_electrons: Image<f32>,
    pub i_minus_electrons: Image<f32>,
    pub i_plus_se_electrons: Image<f32>,
    pub i_minus_se_electrons: Image<f32>,
    /// [`flags`] bits (the moments' flags plus clamping and projection).
    pub flags: Image<u8>,
}

/// (I+, I-) = H^-1 (mu, sigma^2 - sigma_read^2) for every pixel (section 6).
///
/// Written as half-sum and half-difference, S = (sigma^2 - sigma_read^2)/g^2 and
/// D = mu/g with g = rho eta, so nothing cancels when det H = 2 g^3 is tiny.
/// Var(I+-) = (Var S + Var D +- 2 Cov(S, D)) / 4 from the moments' sampling
/// (co)variances. A variance below sigma_read^2 is clamped to it and flagged.
pub fn unmix(
    moments: &Moments,
    h: &SkellamMixing,
    options: UnmixOptions,
) -> Result<Separated, SeparationError> {
    let g = h.gain_dn_per_electron;
    SeparationError::check("gain_dn_per_electron", g, g > 0.0, "> 0")?;
    let r = h.read_variance_dn2;
    SeparationError::check("read_variance_dn2", r, r >= 0.0, ">= 0")?;
    let read = if options.subtract_read_noise { r } else { 0.0 };
    let (w, ht) = (moments.width(), moments.height());
    let mut out = Separated {
        i_plus_electrons: Image::new(w, ht),
        i_minus_electrons: Image::new(w, ht),
        i_plus_se_electrons: Image::new(w, ht),
        i_minus_se_electrons: Image::new(w, ht),
        flags: moments.flags.clone(),
    };
    let g2 = g * g;
    for i in 0..w * ht {
        let mut f = out.flags.data[i];
        if f & flags::INSUFFICIENT != 0 {
            out.i_plus_se_electrons.data[i] = f32::INFINITY;
            out.i_minus_se_electrons.data[i] = f32::INFINITY;
            continue;
        }
        let mean = moments.mean_dn.data[i];
        let mut excess = moments.variance_dn2.data[i] - read;
        if excess < 0.0 {
            excess = 0.0;
            f |= flags::VARIANCE_CLAMPED;
        }
        let var_mean = moments.mean_var_dn2.data[i];
        let var_var = moments.variance_var_dn4.data[i];
        let cov = moments.mean_variance_cov_dn3.data[i];
        let sum = excess / g2;
        let diff = mean / g;
        let var_sum = var_var / (g2 * g2);
        let var_diff = var_mean / g2;
        let cov_sd = cov / (g2 * g);
        let mut p = 0.5 * (sum + diff);
        let mut m = 0.5 * (sum - diff);
        let se_p = (0.25 * (var_sum + var_diff + 2.0 * cov_sd)).max(0.0).sqrt();
        let se_m = (0.25 * (var_sum + var_diff - 2.0 * cov_sd)).max(0.0).sqrt();
        if options.nonnegative && (p < 0.0 || m < 0.0) {
            (p, m) = project(g, mean, excess, var_mean, var_var);
            f |= flags::PROJECTED;
        }
        out.i_plus_electrons.data[i] = p as f32;
        out.i_minus_electrons.data[i] = m as f32;
        out.i_plus_se_electrons.data[i] = se_p as f32;
        out.i_minus_se_electrons.data[i] = se_m as f32;
        out.flags.data[i] = f;
    }
    Ok(out)
}

/// Minimizes (mu - g(p - m))^2 / Var mu + (v - g^2 (p + m))^2 / Var v over the
/// boundary of p, m >= 0 (one of them zero) and returns the better feasible point.
fn project(g: f64, mean: f64, excess: f64, var_mean: f64, var_var: f64) -> (f64, f64) {
    const FLOOR: f64 = 1e-30;
    let wm = 1.0 / var_mean.max(FLOOR);
    let wv = 1.0 / var_var.max(FLOOR);
    let g2 = g * g;
    let denom = wm * g2 + wv * g2 * g2;
    let plus = ((wm * g * mean + wv * g2 * excess) / denom).max(0.0);
    let minus = ((-wm * g * mean + wv * g2 * excess) / denom).max(0.0);
    let cost = |p: f64, m: f64| {
        let a = mean - g * (p - m);
        let b = excess - g2 * (p + m);
        wm * a * a + wv * b * b
    };
    if cost(plus, 0.0) <= cost(0.0, minus) {
        (plus, 0.0)
    } else {
        (0.0, minus)
    }
}
