//! The bipolar colour reconstruction of separated channels (section 5.2):
//! R = I+, G = 0, B = I-, both on one scale (the robust maximum over both
//! channels) so their ratio survives; negative and NaN values show as 0.
//! As RGB8, or straight to the y4m stream's Y, U, V planes.

use multiversion::multiversion;

use super::{robust_max_abs, small_uint};
use crate::mode::SeparatedChannels;
use crate::view::yuv444_pixel;

/// Pixels per block: levels of one block live on the stack.
const BLOCK: usize = 256;

/// Levels per electron: full scale (255) at the robust maximum of both.
fn levels_per_electron(ch: &SeparatedChannels) -> f32 {
    let max =
        robust_max_abs(&ch.i_plus_electrons.data).max(robust_max_abs(&ch.i_minus_electrons.data));
    255.0 / max
}

/// round(clamp(v * scale, 0, 255)) with NaN at 0 (the comparison is false
/// for NaN); a select and [`small_uint`], which rounds like `round` without
/// a libm call, so the loops vectorize.
#[inline(always)]
fn level(v: f32, scale: f32) -> u8 {
    let x = v * scale;
    small_uint(if x > 0.0 { x.min(255.0) } else { 0.0 }) as u8
}

/// The levels of one block of I+ (`r`) and I- (`b`).
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn levels(plus: &[f32], minus: &[f32], scale: f32, r: &mut [u8], b: &mut [u8]) {
    for (o, &v) in r.iter_mut().zip(plus) {
        *o = level(v, scale);
    }
    for (o, &v) in b.iter_mut().zip(minus) {
        *o = level(v, scale);
    }
}

/// Writes 3 bytes (R, G, B) per pixel into `out`; pixels beyond a shorter
/// `out` are skipped.
pub fn render_channels_rgb8(ch: &SeparatedChannels, out: &mut [u8]) {
    let scale = levels_per_electron(ch);
    let (mut r, mut b) = ([0u8; BLOCK], [0u8; BLOCK]);
    let blocks = ch
        .i_plus_electrons
        .data
        .chunks(BLOCK)
        .zip(ch.i_minus_electrons.data.chunks(BLOCK));
    for ((plus, minus), out) in blocks.zip(out.chunks_mut(3 * BLOCK)) {
        let n = plus.len().min(minus.len());
        levels(plus, minus, scale, &mut r[..n], &mut b[..n]);
        for ((px, &r), &b) in out.chunks_exact_mut(3).zip(&r[..n]).zip(&b[..n]) {
            px.copy_from_slice(&[r, 0, b]);
        }
    }
}

/// Writes the BT.601 full-range Y, U and V planes of the colours
/// [`render_channels_rgb8`] makes: the bytes
/// [`crate::view::rgb8_to_yuv444_planes`] makes of its output, without it.
/// Pixels beyond the shortest plane are skipped.
pub fn render_channels_yuv444(ch: &SeparatedChannels, y: &mut [u8], u: &mut [u8], v: &mut [u8]) {
    let scale = levels_per_electron(ch);
    yuv_planes(
        &ch.i_plus_electrons.data,
        &ch.i_minus_electrons.data,
        scale,
        y,
        u,
        v,
    );
}

#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn yuv_planes(plus: &[f32], minus: &[f32], scale: f32, y: &mut [u8], u: &mut [u8], v: &mut [u8]) {
    let px = plus.iter().zip(minus);
    for ((((&p, &m), y), u), v) in px.zip(y).zip(u).zip(v) {
        [*y, *u, *v] = yuv444_pixel(level(p, scale), 0, level(m, scale));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::view::{rgb8_to_yuv444_planes, yuv444_planes_mut};

    fn channels(plus: Vec<f32>, minus: Vec<f32>) -> SeparatedChannels {
        let n = plus.len();
        let img = |data| Image {
            width: n,
            height: 1,
            data,
        };
        SeparatedChannels {
            i_plus_electrons: img(plus),
            i_minus_electrons: img(minus),
            i_plus_se_electrons: img(vec![0.0; n]),
            i_minus_se_electrons: img(vec![0.0; n]),
        }
    }

    #[test]
    fn channels_render_red_and_blue() {
        let ch = channels(
            vec![1000.0, 0.0, -5.0, f32::NAN],
            vec![0.0, 500.0, 0.0, 0.0],
        );
        let mut rgb = [9u8; 12];
        render_channels_rgb8(&ch, &mut rgb);
        assert_eq!(&rgb[0..3], &[255, 0, 0]);
        assert_eq!(&rgb[3..6], &[0, 0, 128]);
        assert_eq!(&rgb[6..12], &[0; 6]);
    }

    /// The levels are `(v * scale).clamp(0, 255).round() as u8` (NaN to 0),
    /// and the planes are the RGB's, byte for byte.
    #[test]
    fn levels_and_planes_match_round_and_the_rgb_path() {
        let n = 3 * BLOCK + 37;
        let value = |i: usize| match i % 53 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => f32::NEG_INFINITY,
            3 => -1e9,
            k => (k as f32 - 6.0) * 13.37 + (i % 7) as f32 * 0.25,
        };
        let ch = channels(
            (0..n).map(value).collect(),
            (0..n).map(|i| value(i * 3 + 1)).collect(),
        );
        let scale = levels_per_electron(&ch);
        let mut rgb = vec![0u8; 3 * n];
        render_channels_rgb8(&ch, &mut rgb);
        let round = |v: f32| (v * scale).clamp(0.0, 255.0).round() as u8;
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            let want = [
                round(ch.i_plus_electrons.data[i]),
                0,
                round(ch.i_minus_electrons.data[i]),
            ];
            assert_eq!(px, want, "pixel {i}");
        }
        let (mut direct, mut via_rgb) = (vec![1; 3 * n], vec![2; 3 * n]);
        let [y, u, v] = yuv444_planes_mut(&mut direct);
        render_channels_yuv444(&ch, y, u, v);
        let [y, u, v] = yuv444_planes_mut(&mut via_rgb);
        rgb8_to_yuv444_planes(&rgb, y, u, v);
        assert!(direct == via_rgb);
    }
}
