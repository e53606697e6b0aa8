//! M3: bilateral-weighted mean and variance of one frame (section 6, M3),
//!
//! mu(x) = sum w I / sum w,  sigma^2(x) = sum w (I - mu)^2 / sum w,
//! w = exp(-(I' - I)^2 / 2 sigma_range^2) exp(-|x' - x|^2 / 2 sigma_domain^2),
//!
//! computed exactly here ([`bilateral_exact`], O(r^2) per pixel, f64); the
//! fast variants are [`super::SeparableBilateral`] and [`super::BilateralGrid`].
//! Saturated and non-finite pixels get zero weight and are flagged.

use super::{input_flags, usable, Moments, SeparationError};
use crate::frame::Frame;
use crate::sensor::ParamError;

/// Parameters of M3.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BilateralParams {
    pub sigma_domain_px: f64,
    pub sigma_range_dn: f64,
    /// Window half-width; 0 selects ceil(2.5 sigma_domain).
    pub radius_px: usize,
}

impl BilateralParams {
    pub fn new(sigma_domain_px: f64, sigma_range_dn: f64) -> Self {
        Self {
            sigma_domain_px,
            sigma_range_dn,
            radius_px: 0,
        }
    }

    /// The window half-width actually used.
    pub fn radius(&self) -> usize {
        if self.radius_px > 0 {
            self.radius_px
        } else {
            (2.5 * self.sigma_domain_px).ceil().max(1.0) as usize
        }
    }

    /// The one set of bounds of M3's sigmas (the live mode, `sdid.toml` and
    /// the offline tools): sigma_domain finite and > 0, sigma_range > 0
    /// (infinity: no range weighting).
    pub fn validate(&self) -> Result<(), SeparationError> {
        let d = self.sigma_domain_px;
        SeparationError::check("sigma_domain_px", d, d > 0.0, "> 0, finite")?;
        let r = self.sigma_range_dn;
        // Infinity is a valid limit (no range weighting); NaN and <= 0 are not.
        if r.is_nan() || r <= 0.0 {
            return Err(SeparationError::Parameter(ParamError {
                name: "sigma_range_dn",
                value: r,
                allowed: "> 0",
            }));
        }
        Ok(())
    }

    /// The radius used on a `width x height` frame: taps beyond the frame
    /// contribute nothing, so capping there changes no result.
    pub(crate) fn radius_on(&self, width: usize, height: usize) -> usize {
        self.radius().min(width.max(height))
    }

    /// Domain weights for offsets 0..=r.
    pub(crate) fn domain_weights(&self, r: usize) -> Vec<f64> {
        let k = 0.5 / (self.sigma_domain_px * self.sigma_domain_px);
        (0..=r).map(|d| (-((d * d) as f64) * k).exp()).collect()
    }
}

/// Range weight exp(-d^2 / 2 s^2) that is exactly 1 at d = 0 and exactly 0
/// (never NaN) when the exponent underflows or s is tiny.
#[inline]
fn range_weight(d: f64, inv_two_s2: f64) -> f64 {
    if d == 0.0 {
        1.0
    } else {
        (-(d * d) * inv_two_s2).exp()
    }
}

/// Valid parameters and a non-empty frame: what every M3 variant checks first.
pub(crate) fn check_input(frame: &Frame, params: &BilateralParams) -> Result<(), SeparationError> {
    params.validate()?;
    if frame.dn.is_empty() || !frame.dn.same_size(&frame.saturated) {
        return Err(SeparationError::Empty);
    }
    Ok(())
}

fn finish(out: &mut Moments, i: usize, value: f64, s0: f64, s1: f64, s2: f64, sw2: f64) {
    if !(s0 > 0.0 && s0.is_finite()) {
        out.set_insufficient(i);
        return;
    }
    let m = s1 / s0;
    let var = (s2 / s0 - m * m).max(0.0);
    let n_eff = if sw2 > 0.0 { s0 * s0 / sw2 } else { 1.0 };
    if n_eff < 1.5 {
        // Weighted variance of (effectively) one sample: undefined.
        out.set_insufficient(i);
        out.samples.data[i] = n_eff;
        return;
    }
    out.set_from_central(i, n_eff, value + m, var, 0.0, None);
}

fn flag_input(frame: &Frame, out: &mut Moments, i: usize) {
    out.flags.data[i] |= input_flags(frame, i);
}

/// M3 exactly as in the paper, f64, with the window clipped at the borders.
/// Samples behind each pixel: effective number (sum w)^2 / sum w^2.
pub fn bilateral_exact(frame: &Frame, params: BilateralParams) -> Result<Moments, SeparationError> {
    check_input(frame, &params)?;
    let (w, h) = (frame.width(), frame.height());
    let r = params.radius_on(w, h);
    let wd = params.domain_weights(r);
    let r = r as isize;
    let inv = 0.5 / (params.sigma_range_dn * params.sigma_range_dn);
    let mut out = Moments::new(w, h);
    for y in 0..h as isize {
        for x in 0..w as isize {
            let i = (y as usize) * w + x as usize;
            flag_input(frame, &mut out, i);
            if !usable(frame, i) {
                out.set_insufficient(i);
                continue;
            }
            let c = frame.dn.data[i] as f64;
            let (mut s0, mut s1, mut s2, mut sw2) = (0.0, 0.0, 0.0, 0.0);
            for dy in -r..=r {
                let yy = y + dy;
                if yy < 0 || yy >= h as isize {
                    continue;
                }
                let wy = wd[dy.unsigned_abs()];
                for dx in -r..=r {
                    let xx = x + dx;
                    if xx < 0 || xx >= w as isize {
                        continue;
                    }
                    let j = yy as usize * w + xx as usize;
                    if !usable(frame, j) {
                        continue;
                    }
                    let d = frame.dn.data[j] as f64 - c;
                    let wt = wy * wd[dx.unsigned_abs()] * range_weight(d, inv);
                    s0 += wt;
                    s1 += wt * d;
                    s2 += wt * d * d;
                    sw2 += wt * wt;
                }
            }
            finish(&mut out, i, c, s0, s1, s2, sw2);
        }
    }
    Ok(out)
}
