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

    fn validate(&self) -> Result<(), SeparationError> {
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

/// Entries of the range-weight table per sigma_range, and its reach in sigmas.
const LUT_PER_SIGMA: f32 = 32.0;
const LUT_SIGMAS: f32 = 6.0;

/// exp(-d^2 / 2 s^2) tabulated on |d| in steps of s / 32 up to 6 s (then 0).
struct RangeLut {
    table: Vec<f32>,
    scale: f32,
}

impl RangeLut {
    fn new(sigma_range_dn: f64) -> Self {
        let n = (LUT_PER_SIGMA * LUT_SIGMAS) as usize;
        let mut table: Vec<f32> = (0..n)
            .map(|k| {
                let u = k as f32 / LUT_PER_SIGMA;
                (-0.5 * u * u).exp()
            })
            .collect();
        table.push(0.0);
        let scale = (LUT_PER_SIGMA as f64 / sigma_range_dn).min(1e30) as f32;
        Self { table, scale }
    }

    #[inline]
    fn weight(&self, d: f32) -> f32 {
        let last = self.table.len() - 1;
        // `as usize` saturates, and NaN maps to 0 (only finite d reach here).
        let k = ((d.abs() * self.scale) + 0.5) as usize;
        self.table[k.min(last)]
    }
}

/// Fast M3 (separable approximation, see module docs): O(r) per pixel, f32.
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
    let lut = RangeLut::new(params.sigma_range_dn);
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
        for x in 0..w {
            let c = v[x];
            let (lo, hi) = (x.saturating_sub(r), (x + r + 1).min(w));
            let (mut s0, mut s1, mut s2, mut q0) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
            for xx in lo..hi {
                let d = v[xx] - c;
                let wt = wd[xx.abs_diff(x)] * lut.weight(d) * ok[xx];
                s0 += wt;
                s1 += wt * d;
                s2 += wt * d * d;
                q0 += wt * wt;
            }
            a0[row + x] = s0;
            a1[row + x] = s1;
            a2[row + x] = s2;
            b0[row + x] = q0;
        }
    }
    // Vertical pass: shift each neighbour's moments to this pixel's value.
    let mut out = Moments::new(w, h);
    for y in 0..h {
        let (lo, hi) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let i = y * w + x;
            flag_input(frame, &mut out, i);
            if valid[i] == 0.0 {
                out.set_insufficient(i);
                continue;
            }
            let c = value[i];
            let (mut s0, mut s1, mut s2, mut q0) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
            for yy in lo..hi {
                let j = yy * w + x;
                let d = value[j] - c;
                let wt = wd[yy.abs_diff(y)] * lut.weight(d) * valid[j];
                let (m0, m1) = (a0[j], a1[j]);
                s0 += wt * m0;
                s1 += wt * (m1 + d * m0);
                s2 += wt * (a2[j] + 2.0 * d * m1 + d * d * m0);
                q0 += wt * wt * b0[j];
            }
            finish(
                &mut out, i, c as f64, s0 as f64, s1 as f64, s2 as f64, q0 as f64,
            );
        }
    }
    Ok(out)
}
