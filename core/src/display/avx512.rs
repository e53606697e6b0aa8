//! The display path's AVX-512 (VBMI) kernel: 64 pixels per step from f32
//! values to RGB8 and YUYV, byte-identical to the table path in [`super`].
//! Diverging: each 1024-entry byte plane (R, G, B, Y) is looked up with
//! eight 128-entry `vpermi2b` permutes and a blend tree on index bits 7..9,
//! and the pair chroma is computed from the looked-up R, G, B in 16-bit
//! lanes. Grey: the level is one exact multiply-add of the index, luma and
//! chroma follow by arithmetic. Diverging steps run four at a time, so each
//! plane's table is loaded into registers once per four steps. Written with
//! intrinsics because no vectorizer makes byte permutes of this shape.

use std::arch::x86_64::*;

use archmage::{arcane, SimdToken, X64V4xToken};
use safe_unaligned_simd::x86_64 as mem;

use super::{LUT_HALF, ROUND_BIAS};

/// Pixels per kernel step.
pub(super) const STEP: usize = super::KERNEL_STEP;
/// Diverging steps per table load (see `render`).
const BLOCK_STEPS: usize = 4;

/// One channel's 1024 table entries as 16 vectors' worth of bytes.
pub(super) type Plane = [[u8; 64]; 16];

/// Proof, found at run time, that this CPU runs the kernel (AVX-512 F, BW,
/// VL and VBMI, as every x86-64-v4x CPU has).
#[derive(Clone, Copy)]
pub(super) struct Kernel(X64V4xToken);

impl Kernel {
    pub(super) fn detect() -> Option<Self> {
        X64V4xToken::summon().map(Kernel)
    }

    /// Colours `values[..64 n]` (with `grey`: R = G = B, the levels of
    /// `planes[0]` computed, not looked up) into `rgb` (192 bytes per step)
    /// and `yuyv` (128 bytes per step); an empty output is not written. `n` is the
    /// most whole steps that `values` and each non-empty output hold.
    /// Returns the pixels done (64 n).
    pub(super) fn render(
        self,
        planes: &[Plane; 4],
        grey: bool,
        values: &[f32],
        scale: f32,
        rgb: &mut [u8],
        yuyv: &mut [u8],
    ) -> usize {
        if grey {
            render::<true>(self.0, planes, values, scale, rgb, yuyv)
        } else {
            render::<false>(self.0, planes, values, scale, rgb, yuyv)
        }
    }

    /// `super::count_bracket` 64 values per step: one compare of the
    /// step's largest |x| against the bracket's bottom, and lane counts and
    /// a compress only for the rare steps reaching it. None when the kept
    /// values could overflow `window` (then the caller takes the full
    /// histogram).
    pub(super) fn count_bracket(
        self,
        data: &[f32],
        lo_bits: u32,
        hi_bits: u32,
        window: &mut [u32],
    ) -> Option<(u64, u64, usize)> {
        count_bracket(self.0, data, lo_bits, hi_bits, window)
    }
}

/// Byte `p` of the low (or high) bytes of two `packus_epi32` results: pixel
/// p's index word sits in 128-bit lane (p % 16) / 4 of its vector.
const fn pack_order(high: bool) -> [u8; 64] {
    let mut idx = [0u8; 64];
    let mut p = 0;
    while p < 64 {
        let q = p % 32; // pixel inside its pair of f32 vectors
        let (j, k, second) = (q % 16 / 4, q % 4, q >= 16);
        let word = 8 * j + if second { 4 } else { 0 } + k;
        idx[p] = (2 * word + high as usize + if p >= 32 { 64 } else { 0 }) as u8;
        p += 1;
    }
    idx
}

/// Byte q of RGB output vector `z`: pixel (64 z + q) / 3, channel (64 z + q) % 3.
/// Returns the R/G permute index (G from the second table) and the B index.
const fn rgb_order(z: usize) -> ([u8; 64], [u8; 64], u64) {
    let (mut rg, mut b, mut b_mask) = ([0u8; 64], [0u8; 64], 0u64);
    let mut q = 0;
    while q < 64 {
        let (px, ch) = ((64 * z + q) / 3, (64 * z + q) % 3);
        match ch {
            0 => rg[q] = px as u8,
            1 => rg[q] = 64 + px as u8,
            _ => {
                b[q] = px as u8;
                b_mask |= 1 << q;
            }
        }
        q += 1;
    }
    (rg, b, b_mask)
}

/// Byte q of YUYV output vector `z`: Y0 U Y1 V of pair 16 z + q / 4, Y from
/// the first table, U (even) and V (odd bytes) from the second.
const fn yuyv_order(z: usize) -> [u8; 64] {
    let mut idx = [0u8; 64];
    let mut q = 0;
    while q < 64 {
        let pair = 16 * z + q / 4;
        idx[q] = match q % 4 {
            0 => 2 * pair,
            1 => 64 + 2 * pair,
            2 => 2 * pair + 1,
            _ => 64 + 2 * pair + 1,
        } as u8;
        q += 1;
    }
    idx
}

/// Byte p of pixel order from two `packus_epi16` of `packus_epi32`
/// results: pixel 16 v + j of f32 vector v sits at 16 (j / 4) + 4 v + j % 4.
const fn grey_order() -> [u8; 64] {
    let mut idx = [0u8; 64];
    let mut p = 0;
    while p < 64 {
        let (v, j) = (p / 16, p % 16);
        idx[p] = (16 * (j / 4) + 4 * v + j % 4) as u8;
        p += 1;
    }
    idx
}

/// Byte q of RGB output vector `z` when R = G = B: pixel (64 z + q) / 3.
const fn grey_rgb_order(z: usize) -> [u8; 64] {
    let mut idx = [0u8; 64];
    let mut q = 0;
    while q < 64 {
        idx[q] = ((64 * z + q) / 3) as u8;
        q += 1;
    }
    idx
}

const GREY_ORDER: [u8; 64] = grey_order();
const GREY_RGB: [[u8; 64]; 3] = [grey_rgb_order(0), grey_rgb_order(1), grey_rgb_order(2)];
const PACK_LO: [u8; 64] = pack_order(false);
const PACK_HI: [u8; 64] = pack_order(true);
const RGB: [([u8; 64], [u8; 64], u64); 3] = [rgb_order(0), rgb_order(1), rgb_order(2)];
const YUYV: [[u8; 64]; 2] = [yuyv_order(0), yuyv_order(1)];

#[arcane]
fn render<const GREY: bool>(
    _token: X64V4xToken,
    planes: &[Plane; 4],
    values: &[f32],
    scale: f32,
    rgb: &mut [u8],
    yuyv: &mut [u8],
) -> usize {
    let mut n = values.len() / STEP;
    if !rgb.is_empty() {
        n = n.min(rgb.len() / (3 * STEP));
    }
    if !yuyv.is_empty() {
        n = n.min(yuyv.len() / (2 * STEP));
    }
    let vscale = _mm512_set1_ps(scale);
    let one = _mm512_set1_ps(1.0);
    let (half, bias) = (_mm512_set1_ps(LUT_HALF), _mm512_set1_ps(ROUND_BIAS));
    let nan_to_zero = _mm512_set1_epi32(0x88);
    macro_rules! load {
        ($b:expr) => {
            mem::_mm512_loadu_si512::<[u8; 64]>($b)
        };
    }
    let (pack_lo, pack_hi) = (load!(&PACK_LO), load!(&PACK_HI));
    let rgb_idx = RGB.map(|(rg, b, mask)| (load!(&rg), load!(&b), mask));
    let yuyv_idx = YUYV.map(|i| load!(&i));
    let grey_rgb_idx = GREY_RGB.map(|i| load!(&i));
    let grey_order = load!(&GREY_ORDER);
    let (grey_step, grey_offset) = (_mm512_set1_ps(255.0 / 1022.0), _mm512_set1_ps(0.5004));
    let (bit7, bit8, bit9) = (
        _mm512_set1_epi8(0x80u8 as i8),
        _mm512_set1_epi8(1),
        _mm512_set1_epi8(2),
    );
    // Table index of 16 values: round((t + 1) * 511), t = v * scale in
    // [-1, 1], NaN -> 0, exactly as `super::lut_indices` computes it. Only
    // the top is clamped here: t below -1 gives an index below 0 (or
    // i32::MIN), which the unsigned saturating packs below turn into 0.
    macro_rules! index {
        ($v:expr) => {{
            let v: __m512 = $v;
            let t = _mm512_mul_ps(v, vscale);
            // NaN (classes 0 and 1: QNaN, SNaN) becomes +0 (response 8);
            // every other class keeps its value (response 0).
            let t = _mm512_fixupimm_ps::<0>(t, t, nan_to_zero);
            let t = _mm512_min_ps(t, one);
            let x = _mm512_mul_ps(_mm512_add_ps(t, one), half);
            _mm512_cvttps_epi32(_mm512_add_ps(x, bias))
        }};
    }
    let (mut scratch_rgb, mut scratch_yuyv) = ([0u8; 3 * STEP], [0u8; 2 * STEP]);
    let (chunks, _) = values.as_chunks::<STEP>();
    // The 64 table indices of a step's values, as four vectors of 16.
    macro_rules! indices {
        ($chunk:expr) => {{
            let chunk: &[f32; STEP] = $chunk;
            let (quads, _) = chunk.as_chunks::<16>();
            let mut i = [_mm512_setzero_si512(); 4];
            for (i, q) in i.iter_mut().zip(quads) {
                *i = index!(mem::_mm512_loadu_ps(q));
            }
            i
        }};
    }
    // Writes step `c`'s RGB and YUYV bytes from its R, G, B and luma bytes.
    macro_rules! emit {
        ($c:expr, $r:expr, $g:expr, $b:expr, $y:expr) => {{
            let (c, r, g, b, y): (usize, __m512i, __m512i, __m512i, __m512i) = ($c, $r, $g, $b, $y);
            if !rgb.is_empty() {
                let dst = rgb
                    .get_mut(3 * STEP * c..3 * STEP * (c + 1))
                    .unwrap_or(&mut scratch_rgb);
                let (dst, _) = dst.as_chunks_mut::<64>();
                if GREY {
                    // One single-source permute per vector: R = G = B.
                    for (d, &idx) in dst.iter_mut().zip(&grey_rgb_idx) {
                        mem::_mm512_storeu_si512(d, _mm512_permutexvar_epi8(idx, g));
                    }
                } else {
                    for (d, &(rg_idx, b_idx, b_mask)) in dst.iter_mut().zip(&rgb_idx) {
                        let rg = _mm512_permutex2var_epi8(r, rg_idx, g);
                        mem::_mm512_storeu_si512(
                            d,
                            _mm512_mask_permutexvar_epi8(rg, b_mask, b_idx, b),
                        );
                    }
                }
            }
            if !yuyv.is_empty() {
                // Glue's ((-38 r - 74 g + 112 b + 256) >> 9) + 128 of the pair
                // sums as (inner + 128) >> 8 + 128, inner with the halved
                // coefficients: `maddubs` multiplies each byte and adds the
                // pair (|inner| <= 56 * 510, no saturation), and the offset
                // 128 + (128 << 8) makes the sum non-negative, so one logical
                // shift (U) or mask (V, already in the high byte) finishes it.
                let uv = if GREY {
                    // R = G = B: U and V are 128 (the coefficients sum to 0).
                    _mm512_set1_epi16(0x8080_u16 as i16)
                } else {
                    macro_rules! chroma {
                        ($cr:expr, $cg:expr, $cb:expr) => {{
                            let (cr, cg, cb): (i8, i8, i8) = ($cr, $cg, $cb);
                            _mm512_add_epi16(
                                _mm512_add_epi16(
                                    _mm512_maddubs_epi16(r, _mm512_set1_epi8(cr)),
                                    _mm512_maddubs_epi16(g, _mm512_set1_epi8(cg)),
                                ),
                                _mm512_add_epi16(
                                    _mm512_maddubs_epi16(b, _mm512_set1_epi8(cb)),
                                    _mm512_set1_epi16(0x8080_u16 as i16),
                                ),
                            )
                        }};
                    }
                    let u = _mm512_srli_epi16::<8>(chroma!(-19, -37, 56));
                    let v = _mm512_and_si512(
                        chroma!(56, -47, -9),
                        _mm512_set1_epi16(0xff00_u16 as i16),
                    );
                    _mm512_or_si512(u, v)
                };
                let dst = yuyv
                    .get_mut(2 * STEP * c..2 * STEP * (c + 1))
                    .unwrap_or(&mut scratch_yuyv);
                let (dst, _) = dst.as_chunks_mut::<64>();
                for (d, &idx) in dst.iter_mut().zip(&yuyv_idx) {
                    mem::_mm512_storeu_si512(d, _mm512_permutex2var_epi8(y, idx, uv));
                }
            }
        }};
    }
    if GREY {
        for (c, chunk) in chunks.iter().enumerate().take(n) {
            let i = indices!(chunk);
            // The grey table holds round(i * 255 / 1022) (halves up): one
            // fused multiply-add per 16 indices, exact for every index
            // (the nearest non-tie lies 1/1022 from a half, the offset
            // 0.0004), then saturating packs (negative -> 0) and one
            // permute into pixel order.
            let level = i.map(|i| {
                _mm512_cvttps_epi32(_mm512_fmadd_ps(
                    _mm512_cvtepi32_ps(i),
                    grey_step,
                    grey_offset,
                ))
            });
            let bytes = _mm512_packus_epi16(
                _mm512_packus_epi32(level[0], level[1]),
                _mm512_packus_epi32(level[2], level[3]),
            );
            let g = _mm512_permutexvar_epi8(grey_order, bytes);
            // Limited-range luma of grey g: ((220 g + 128) >> 8) + 16, the
            // table's value, for even and odd pixels in 16-bit lanes (< 2^16).
            macro_rules! luma {
                ($g:expr) => {
                    _mm512_add_epi16(
                        _mm512_srli_epi16::<8>(_mm512_add_epi16(
                            _mm512_mullo_epi16($g, _mm512_set1_epi16(220)),
                            _mm512_set1_epi16(128),
                        )),
                        _mm512_set1_epi16(16),
                    )
                };
            }
            let even = luma!(_mm512_and_si512(g, _mm512_set1_epi16(0xff)));
            let odd = luma!(_mm512_srli_epi16::<8>(g));
            let y = _mm512_or_si512(even, _mm512_slli_epi16::<8>(odd));
            emit!(c, g, g, g, y);
        }
        return n * STEP;
    }
    // Diverging, `$steps` steps at a time: their indices first, then each
    // plane's 16 table vectors loaded once (they stay in registers) for all
    // the steps' lookups, then the outputs. Plane by plane, not step by
    // step: 64 table vectors do not fit the 32 registers, and reloading
    // them for every step cost more than the lookups.
    macro_rules! block {
        ($steps:expr, $c0:expr) => {{
            let c0: usize = $c0;
            let mut lo = [_mm512_setzero_si512(); $steps];
            let mut bits = [(0u64, 0u64, 0u64); $steps];
            for (s, (lo, bits)) in lo.iter_mut().zip(&mut bits).enumerate() {
                let i = indices!(&chunks[c0 + s]);
                let w01 = _mm512_packus_epi32(i[0], i[1]);
                let w23 = _mm512_packus_epi32(i[2], i[3]);
                *lo = _mm512_permutex2var_epi8(w01, pack_lo, w23);
                let hi = _mm512_permutex2var_epi8(w01, pack_hi, w23);
                *bits = (
                    _mm512_test_epi8_mask(*lo, bit7),
                    _mm512_test_epi8_mask(hi, bit8),
                    _mm512_test_epi8_mask(hi, bit9),
                );
            }
            let mut out = [[_mm512_setzero_si512(); $steps]; 4];
            // Luma (the last plane) only feeds YUYV.
            let used = if yuyv.is_empty() { 3 } else { 4 };
            for (plane, out) in planes.iter().zip(&mut out).take(used) {
                let t: [__m512i; 16] = std::array::from_fn(|k| load!(&plane[k]));
                for ((out, &lo), &(m7, m8, m9)) in out.iter_mut().zip(&lo).zip(&bits) {
                    // Each pair of 128-entry pieces is two masked `vpermi2b`s:
                    // lanes with index bit 7 clear take the first piece's
                    // entry, and the second permute (masked to bit 7 set)
                    // leaves them alone; bits 8 and 9 then pick the pair by
                    // blends.
                    let pair = |k: usize| {
                        let x = _mm512_mask2_permutex2var_epi8(t[k], lo, !m7, t[k + 1]);
                        _mm512_mask2_permutex2var_epi8(t[k + 2], x, m7, t[k + 3])
                    };
                    let c0 = _mm512_mask_blend_epi8(m8, pair(0), pair(4));
                    let c1 = _mm512_mask_blend_epi8(m8, pair(8), pair(12));
                    *out = _mm512_mask_blend_epi8(m9, c0, c1);
                }
            }
            for s in 0..$steps {
                emit!(c0 + s, out[0][s], out[1][s], out[2][s], out[3][s]);
            }
        }};
    }
    // RGB alone (three planes, 48 table vectors) measured faster one step
    // at a time.
    let full = if yuyv.is_empty() {
        0
    } else {
        n / BLOCK_STEPS * BLOCK_STEPS
    };
    for c0 in (0..full).step_by(BLOCK_STEPS) {
        block!(BLOCK_STEPS, c0);
    }
    for c in full..n {
        block!(1, c);
    }
    n * STEP
}

#[arcane]
fn count_bracket(
    _token: X64V4xToken,
    data: &[f32],
    lo_bits: u32,
    hi_bits: u32,
    window: &mut [u32],
) -> Option<(u64, u64, usize)> {
    let abs = _mm512_set1_epi32(0x7fff_ffff);
    let inf = _mm512_set1_epi32(super::INF_BITS as i32);
    let (lo, hi) = (
        _mm512_set1_epi32(lo_bits as i32),
        _mm512_set1_epi32(hi_bits as i32),
    );
    // Values at or above the bracket's bottom (the top percent or so, and
    // every NaN and Inf, whose |x| bits lie above any finite value's) are
    // rare: a step of 64 values costs four masks and three maxima, and only
    // steps holding such values are counted lane by lane. Then values
    // below = all - at or above, finite = all - non-finite.
    let (mut at_or_above, mut non_finite) = (0u64, 0u64);
    let mut kept = 0usize;
    // Last value first: the colour pass that follows reads from the start,
    // which is then what the L2 cache still holds.
    let (steps, rest) = data.as_chunks::<64>();
    for step in steps.iter().rev() {
        let (quads, _) = step.as_chunks::<16>();
        let bits: [__m512i; 4] = std::array::from_fn(|k| {
            _mm512_and_si512(_mm512_castps_si512(mem::_mm512_loadu_ps(&quads[k])), abs)
        });
        let top = _mm512_max_epu32(
            _mm512_max_epu32(bits[0], bits[1]),
            _mm512_max_epu32(bits[2], bits[3]),
        );
        if _mm512_cmpge_epu32_mask(top, lo) == 0 {
            continue;
        }
        for &b in &bits {
            let high = _mm512_cmpge_epu32_mask(b, lo);
            if high == 0 {
                continue;
            }
            at_or_above += u64::from(high.count_ones());
            non_finite += u64::from(_mm512_cmpge_epu32_mask(b, inf).count_ones());
            let inside = _mm512_mask_cmplt_epu32_mask(high, b, hi);
            if inside != 0 {
                let dst: &mut [u32; 16] = window.get_mut(kept..kept + 16)?.try_into().ok()?;
                mem::_mm512_storeu_epi32(dst, _mm512_maskz_compress_epi32(inside, b));
                kept += inside.count_ones() as usize;
            }
        }
    }
    // The last partial step (under 64 values): the portable pass, into
    // what is left of the window.
    let (rest_finite, rest_below, rest_kept) =
        super::count_bracket(rest, lo_bits, hi_bits, window.get_mut(kept..)?)?;
    let all = (steps.len() * 64) as u64;
    Some((
        all - non_finite + rest_finite,
        all - at_or_above + rest_below,
        kept + rest_kept,
    ))
}
