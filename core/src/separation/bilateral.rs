//! M3: bilateral-weighted mean and variance of one frame (section 6, M3),
//!
//! mu(x) = sum w I / sum w,  sigma^2(x) = sum w (I - mu)^2 / sum w,
//! w = exp(-(I' - I)^2 / 2 sigma_range^2) exp(-|x' - x|^2 / 2 sigma_domain^2),
//!
//! computed exactly ([`bilateral_exact`], O(r^2) per pixel) and by a separable
//! approximation ([`bilateral_separable`], O(r) per pixel): a horizontal pass
//! gathers weighted moments along rows, a vertical pass combines them with the
//! range weight between column neighbours, i.e. the 2-D range weight
//! w_r(I(x+dx, y+dy) - I(x, y)) is replaced by
//! w_r(I(x+dx, y+dy) - I(x, y+dy)) w_r(I(x, y+dy) - I(x, y)). Moments are kept
//! about each pixel's own value (shifted when combined), so f32 is enough.
//! Saturated and non-finite pixels get zero weight and are flagged.

use super::{input_flags, usable, Moments, SeparationError};
use crate::frame::Frame;

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

    pub(crate) fn validate(&self) -> Result<(), SeparationError> {
        let d = self.sigma_domain_px;
        SeparationError::check("sigma_domain_px", d, d > 0.0, "> 0, finite")?;
        let r = self.sigma_range_dn;
        // Infinity is a valid limit (no range weighting); NaN and <= 0 are not.
        if r.is_nan() || r <= 0.0 {
            return Err(SeparationError::Parameter {
                name: "sigma_range_dn",
                value: r,
                allowed: "> 0",
            });
        }
        Ok(())
    }

    fn domain_weights(&self) -> Vec<f64> {
        let r = self.radius();
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

fn check_frame(frame: &Frame) -> Result<(), SeparationError> {
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
    params.validate()?;
    check_frame(frame)?;
    let (w, h) = (frame.width(), frame.height());
    let r = params.radius() as isize;
    let wd = params.domain_weights();
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

/// exp(-t) for t >= 0 without branches or tables, so row loops vectorize:
/// 2^-y = 2^-n 2^-f with n = trunc(y), the fraction by a degree-6 Taylor
/// polynomial (relative error < 2e-5); t is capped at 80 (weight ~1e-35).
#[inline(always)]
fn exp_neg(t: f32) -> f32 {
    let y = t.clamp(0.0, 80.0) * std::f32::consts::LOG2_E;
    let n = y as i32;
    let u = (y - n as f32) * std::f32::consts::LN_2;
    // e^-u for u in [0, ln 2).
    let p = 1.0
        - u * (1.0
            - u * (0.5
                - u * (1.0 / 6.0 - u * (1.0 / 24.0 - u * (1.0 / 120.0 - u * (1.0 / 720.0))))));
    p * f32::from_bits(((127 - n) as u32) << 23)
}

/// Fast M3 (separable approximation, see module docs): O(r) per pixel, f32,
/// row-at-a-time loops the compiler vectorizes.
pub fn bilateral_separable(
    frame: &Frame,
    params: BilateralParams,
) -> Result<Moments, SeparationError> {
    params.validate()?;
    check_frame(frame)?;
    let (w, h) = (frame.width(), frame.height());
    let n = w * h;
    let r = params.radius();
    let wd: Vec<f32> = params.domain_weights().iter().map(|&v| v as f32).collect();
    // Finite even when sigma_range underflows, so d = 0 always gives weight 1.
    let k = (0.5 / (params.sigma_range_dn * params.sigma_range_dn)).min(1e30) as f32;
    // Unusable pixels: value 0 and validity 0, so they never contribute.
    let mut value = vec![0.0f32; n];
    let mut valid = vec![0.0f32; n];
    for i in 0..n {
        if usable(frame, i) {
            value[i] = frame.dn.data[i];
            valid[i] = 1.0;
        }
    }
    // Horizontal pass: moments about each pixel's own value.
    let (mut a0, mut a1, mut a2, mut b0) = (
        vec![0.0f32; n],
        vec![0.0f32; n],
        vec![0.0f32; n],
        vec![0.0f32; n],
    );
    for y in 0..h {
        let row = y * w;
        let v = &value[row..row + w];
        let ok = &valid[row..row + w];
        let (s0, s1, s2, q0) = (
            &mut a0[row..row + w],
            &mut a1[row..row + w],
            &mut a2[row..row + w],
            &mut b0[row..row + w],
        );
        for dx in -(r as isize)..=(r as isize) {
            let wdx = wd[dx.unsigned_abs()];
            // x and x + dx both inside the row.
            let lo = (-dx).max(0) as usize;
            let hi = (w as isize - dx.max(0)).max(0) as usize;
            if lo >= hi {
                continue;
            }
            let off = (lo as isize + dx) as usize;
            let len = hi - lo;
            let (vc, vn, okn) = (&v[lo..hi], &v[off..off + len], &ok[off..off + len]);
            let (t0, t1, t2, t3) = (
                &mut s0[lo..hi],
                &mut s1[lo..hi],
                &mut s2[lo..hi],
                &mut q0[lo..hi],
            );
            for x in 0..len {
                let d = vn[x] - vc[x];
                let wt = wdx * exp_neg(d * d * k) * okn[x];
                t0[x] += wt;
                t1[x] += wt * d;
                t2[x] += wt * d * d;
                t3[x] += wt * wt;
            }
        }
    }
    // Vertical pass: shift each neighbour's moments to this pixel's value.
    let mut out = Moments::new(w, h);
    let (mut s0, mut s1, mut s2, mut q0) = (
        vec![0.0f32; w],
        vec![0.0f32; w],
        vec![0.0f32; w],
        vec![0.0f32; w],
    );
    for y in 0..h {
        s0.fill(0.0);
        s1.fill(0.0);
        s2.fill(0.0);
        q0.fill(0.0);
        let (lo, hi) = (y.saturating_sub(r), (y + r + 1).min(h));
        let row = y * w;
        let vc = &value[row..row + w];
        for yy in lo..hi {
            let wdy = wd[yy.abs_diff(y)];
            let j = yy * w;
            let (vn, okn) = (&value[j..j + w], &valid[j..j + w]);
            let (m0, m1, m2, mb) = (&a0[j..j + w], &a1[j..j + w], &a2[j..j + w], &b0[j..j + w]);
            for x in 0..w {
                let d = vn[x] - vc[x];
                let wt = wdy * exp_neg(d * d * k) * okn[x];
                s0[x] += wt * m0[x];
                s1[x] += wt * (m1[x] + d * m0[x]);
                s2[x] += wt * (m2[x] + 2.0 * d * m1[x] + d * d * m0[x]);
                q0[x] += wt * wt * mb[x];
            }
        }
        for x in 0..w {
            let i = row + x;
            out.flags.data[i] |= input_flags(frame, i);
            if valid[i] == 0.0 {
                out.set_insufficient(i);
                continue;
            }
            finish(
                &mut out,
                i,
                vc[x] as f64,
                s0[x] as f64,
                s1[x] as f64,
                s2[x] as f64,
                q0[x] as f64,
            );
        }
    }
    Ok(out)
}
