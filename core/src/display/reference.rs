//! The scalar display path: the plain reference the fast one in [`super`]
//! is tested (byte for byte) and benchmarked against.

use super::{Colormap, DisplayMap, AUTO_PERCENTILE, DIVERGING, LUT_HALF, LUT_SIZE};
use crate::image::Image;

/// Scalar `DisplayMap::render_rgb8`: a LUT built per call, a float
/// `round` per pixel.
pub fn render_rgb8(map: &DisplayMap, img: &Image<f32>, out: &mut [u8]) {
    let mut lut = [[0u8; 3]; LUT_SIZE];
    for (i, c) in lut.iter_mut().enumerate() {
        let t = i as f32 / LUT_HALF - 1.0;
        *c = match map.colormap {
            Colormap::Diverging => diverging(t),
            Colormap::Grey => [grey(t); 3],
        };
    }
    let scale = 1.0 / max_abs_dn(map, img);
    for (px, &v) in out.chunks_exact_mut(3).zip(&img.data) {
        let t = normalized(v, scale);
        px.copy_from_slice(&lut[((t + 1.0) * LUT_HALF).round() as usize]);
    }
}

/// Scalar `DisplayMap::render_grey8`.
pub fn render_grey8(map: &DisplayMap, img: &Image<f32>, out: &mut [u8]) {
    let scale = 1.0 / max_abs_dn(map, img);
    for (px, &v) in out.iter_mut().zip(&img.data) {
        *px = grey(normalized(v, scale));
    }
}

fn max_abs_dn(map: &DisplayMap, img: &Image<f32>) -> f32 {
    match map.range {
        super::DisplayRange::Fixed { max_abs_dn } if max_abs_dn.is_finite() && max_abs_dn > 0.0 => {
            max_abs_dn
        }
        _ => robust_max_abs(&img.data),
    }
}

/// v / max in [-1, 1]; NaN maps to 0 (neutral), +-Inf to the ends.
fn normalized(v: f32, scale: f32) -> f32 {
    let t = v * scale;
    if t.is_nan() {
        0.0
    } else {
        t.clamp(-1.0, 1.0)
    }
}

/// Grey level of t in [-1, 1].
pub fn grey(t: f32) -> u8 {
    ((t + 1.0) * 127.5).round() as u8
}

/// Diverging colour of t in [-1, 1]: linear between the anchors.
pub fn diverging(t: f32) -> [u8; 3] {
    let x = (t + 1.0) * 2.0; // 0..=4 across the anchors
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    let (a, b) = (DIVERGING[i], DIVERGING[i + 1]);
    std::array::from_fn(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
}

/// Scalar `robust_max_abs`: two histogram passes with one histogram.
pub fn robust_max_abs(data: &[f32]) -> f32 {
    const COARSE_SHIFT: u32 = 20;
    const FINE_SHIFT: u32 = 9;
    const BINS: usize = 2048;
    let mut coarse = [0u32; BINS];
    let mut finite = 0u64;
    let mut max_abs = 0.0f32;
    for &v in data {
        if v.is_finite() {
            let a = v.abs();
            coarse[(a.to_bits() >> COARSE_SHIFT) as usize] += 1;
            finite += 1;
            max_abs = max_abs.max(a);
        }
    }
    if finite == 0 || max_abs == 0.0 {
        return 1.0;
    }
    let rank = ((AUTO_PERCENTILE * finite as f64).ceil() as u64).clamp(1, finite) - 1;
    let (bin, below) = find_bin(&coarse, rank);
    let mut fine = [0u32; BINS];
    let mut fine_max = [0.0f32; BINS];
    for &v in data {
        if v.is_finite() {
            let a = v.abs();
            let bits = a.to_bits();
            if (bits >> COARSE_SHIFT) as usize == bin {
                let i = ((bits & ((1 << COARSE_SHIFT) - 1)) >> FINE_SHIFT) as usize;
                fine[i] += 1;
                fine_max[i] = fine_max[i].max(a);
            }
        }
    }
    let q = fine_max[find_bin(&fine, rank - below).0];
    if q >= f32::MIN_POSITIVE {
        q
    } else {
        max_abs
    }
}

fn find_bin(hist: &[u32], rank: u64) -> (usize, u64) {
    let mut below = 0u64;
    for (i, &n) in hist.iter().enumerate() {
        if below + u64::from(n) > rank {
            return (i, below);
        }
        below += u64::from(n);
    }
    (hist.len() - 1, below)
}
