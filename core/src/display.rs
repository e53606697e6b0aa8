//! Display mapping of signed DN images to 8-bit pixels, called by sinks (not a
//! pipeline stage). Diverging: negative blue, zero near-white, positive red,
//! as in the paper's figures; or grey with zero at mid-grey. The range is
//! symmetric about zero, either fixed or taken from a high percentile of |x|
//! so a few outliers (hot pixels, saturation, NaN/Inf) do not wash it out.

#[cfg(target_arch = "x86_64")]
mod avx512;
mod channels;
pub mod reference;

pub use channels::{render_channels_rgb8, render_channels_yuv444};

use std::str::FromStr;
use std::sync::OnceLock;

use multiversion::multiversion;

#[cfg(target_arch = "x86_64")]
use avx512::Kernel;

/// No vector kernel off x86-64: the table path does every pixel.
#[cfg(not(target_arch = "x86_64"))]
#[derive(Clone, Copy)]
struct Kernel;

#[cfg(not(target_arch = "x86_64"))]
impl Kernel {
    fn detect() -> Option<Self> {
        None
    }
    fn render(
        self,
        _: &[[[u8; 64]; 16]; 4],
        _: bool,
        _: &[f32],
        _: f32,
        _: &mut [u8],
        _: &mut [u8],
    ) -> usize {
        0
    }
    fn count_bracket(self, _: &[f32], _: u32, _: u32, _: &mut [u32]) -> Option<(u64, u64, usize)> {
        None
    }
}
use crate::image::Image;
use crate::mode::ModeOutput;
use crate::view::yuv444_pixel;

/// Largest fixed display range, |DN| at full scale.
pub const MAX_RANGE_DN: f64 = 1e6;

/// Fraction of finite pixels whose |x| lies inside the auto range.
pub const AUTO_PERCENTILE: f64 = 0.995;

crate::named_enum! {
    /// Colour scale, named "diverging" or "grey" ("gray" is accepted too).
    #[derive(Default)]
    #[strum(
        serialize_all = "lowercase",
        parse_err_ty = DisplayParseError,
        parse_err_fn = unknown_colormap
    )]
    pub enum Colormap {
        /// Negative blue, zero near-white, positive red.
        #[default]
        Diverging,
        /// Black (most negative) to white (most positive), zero mid-grey.
        #[strum(to_string = "grey", serialize = "gray")]
        Grey,
    }
}

fn unknown_colormap(s: &str) -> DisplayParseError {
    DisplayParseError::Colormap(s.to_owned())
}

/// Which |DN| maps to the ends of the scale.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum DisplayRange {
    /// +-(the 99.5th percentile of |x| over finite pixels), never 0 or NaN.
    #[default]
    SymmetricAuto,
    /// +-max_abs_dn.
    Fixed { max_abs_dn: f32 },
}

/// A name or number that is not a display setting.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DisplayParseError {
    #[error("unknown colormap '{0}'; valid colormaps: diverging, grey")]
    Colormap(String),
    #[error("invalid range '{0}'; expected 'auto' or a finite number of DN > 0")]
    Range(String),
}

impl FromStr for DisplayRange {
    type Err = DisplayParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "auto" {
            return Ok(DisplayRange::SymmetricAuto);
        }
        match s.parse::<f32>() {
            Ok(v) if v.is_finite() && v > 0.0 => Ok(DisplayRange::Fixed { max_abs_dn: v }),
            _ => Err(DisplayParseError::Range(s.to_owned())),
        }
    }
}

/// Colormap plus range: everything a sink needs to show a signed image.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DisplayMap {
    pub colormap: Colormap,
    pub range: DisplayRange,
}

const LUT_SIZE: usize = 1023;
const LUT_HALF: f32 = ((LUT_SIZE - 1) / 2) as f32;
/// The largest f32 below 0.5: trunc(x + ROUND_BIAS) equals `x.round()` for
/// every finite x >= 0 (the expansion LLVM itself uses), without a libm call,
/// so the per-pixel loops vectorize.
const ROUND_BIAS: f32 = 0.499_999_97;
/// Pixels per step of the vector kernel.
const KERNEL_STEP: usize = 64;
/// Pixels per block: indices of one block live on the stack.
const BLOCK: usize = 256;

/// Diverging anchors at t = -1, -0.5, 0, 0.5, 1 (a red-blue scale).
const DIVERGING: [[f32; 3]; 5] = [
    [33.0, 102.0, 172.0],
    [103.0, 169.0, 207.0],
    [247.0, 247.0, 247.0],
    [239.0, 138.0, 98.0],
    [178.0, 24.0, 43.0],
];

/// One colormap's tables over [-1, 1] in steps of 1/511 (finer than 8-bit
/// output), built once. 1024 entries so a 10-bit index needs no bounds check.
struct Tables {
    /// R | G << 8 | B << 16.
    rgb: [u32; 1024],
    /// The colour's BT.601 full-range Y | U << 8 | V << 16 (the y4m
    /// stream's, [`crate::view::rgb8_to_yuv444_planes`]).
    yuv: [u32; 1024],
    /// YUYV of a pixel pair is `yuyv_word(first[i0] + second[i1])`: each
    /// entry holds the colour's BT.601 U and V (biased, see [`CHROMA_BIAS`])
    /// at bits 0 and 32, so one add sums the pair's chroma without carries
    /// (each sum < 2^17), and its limited-range luma at bit 50 (`first`) or
    /// 18 (`second`): one shift and mask puts each byte in place.
    first: [u64; 1024],
    second: [u64; 1024],
    /// R, G, B and limited-range luma bytes, entry i at `[i / 64][i % 64]`
    /// (the AVX-512 kernel's byte tables).
    planes: [[[u8; 64]; 16]; 4],
}

/// Per pixel: half the chroma offset 128 << 9 plus half the rounding 256,
/// so (U0 + U1 + 2 * CHROMA_BIAS) >> 9 is `view`'s packing
/// ((U0 + U1 + 256) >> 9) + 128; |U|, |V| <= 112 * 255 keep each biased
/// value in 0..2^16 and the pair sum's byte in 16..=240.
const CHROMA_BIAS: i32 = (128 << 8) + 128;

/// The YUYV bytes of a sum of a `first` and a `second` table entry.
#[inline(always)]
fn yuyv_word(sum: u64) -> u32 {
    let y0 = (sum >> 50) & 0xff;
    let u = (sum >> 1) & 0xff00; // bits 9..16 of the U sum
    let y1 = (sum >> 2) & 0xff_0000;
    let v = (sum >> 17) & 0xff00_0000; // bits 9..16 of the V sum
    (y0 | u | y1 | v) as u32
}

impl Tables {
    fn build(colormap: Colormap) -> Self {
        let mut t = Tables {
            rgb: [0; 1024],
            yuv: [0; 1024],
            first: [0; 1024],
            second: [0; 1024],
            planes: [[[0; 64]; 16]; 4],
        };
        for i in 0..1024 {
            let x = i.min(LUT_SIZE - 1) as f32 / LUT_HALF - 1.0;
            let c = match colormap {
                Colormap::Diverging => reference::diverging(x),
                Colormap::Grey => [reference::grey(x); 3],
            };
            let [r, g, b] = c.map(i32::from);
            t.rgb[i] = u32::from_le_bytes([c[0], c[1], c[2], 0]);
            let [y, u, v] = yuv444_pixel(c[0], c[1], c[2]);
            t.yuv[i] = u32::from_le_bytes([y, u, v, 0]);
            let luma = ((((66 * r + 129 * g + 25 * b + 128) >> 8) + 16) & 0xff) as u64;
            let u = (-38 * r - 74 * g + 112 * b + CHROMA_BIAS) as u64;
            let v = (112 * r - 94 * g - 18 * b + CHROMA_BIAS) as u64;
            t.first[i] = u | v << 32 | luma << 50;
            t.second[i] = u | v << 32 | luma << 18;
            for (plane, byte) in t.planes.iter_mut().zip([c[0], c[1], c[2], luma as u8]) {
                plane[i / 64][i % 64] = byte;
            }
        }
        t
    }

    fn get(colormap: Colormap) -> &'static Tables {
        static DIVERGING_TABLES: OnceLock<Tables> = OnceLock::new();
        static GREY_TABLES: OnceLock<Tables> = OnceLock::new();
        match colormap {
            Colormap::Diverging => DIVERGING_TABLES.get_or_init(|| Tables::build(colormap)),
            Colormap::Grey => GREY_TABLES.get_or_init(|| Tables::build(colormap)),
        }
    }
}

impl DisplayMap {
    pub fn new(colormap: Colormap, range: DisplayRange) -> Self {
        Self { colormap, range }
    }

    /// The |DN| mapped to the ends of the scale for `img`: finite and > 0.
    pub fn max_abs_dn(&self, img: &Image<f32>) -> f32 {
        match self.range {
            DisplayRange::Fixed { max_abs_dn } if max_abs_dn.is_finite() && max_abs_dn > 0.0 => {
                max_abs_dn
            }
            _ => robust_max_abs(&img.data),
        }
    }

    /// Writes 3 bytes (R, G, B) per pixel into `out` (length 3 * width * height;
    /// pixels beyond a shorter `out` are skipped). Uses the selected colormap.
    pub fn render_rgb8(&self, img: &Image<f32>, out: &mut [u8]) {
        self.render_rgb8_yuyv(img, out, &mut []);
    }

    /// Writes YUYV (BT.601 limited range, 2 bytes per pixel, chroma from the
    /// mean of each horizontal pixel pair) of the colormapped image: the
    /// bytes [`crate::view::Packer`]'s RGB to YUYV packing makes of
    /// [`Self::render_rgb8`]'s output. Rows or pairs beyond a shorter `out`
    /// are skipped; with an odd width the last 2 bytes of each row are not written.
    pub fn render_yuyv(&self, img: &Image<f32>, out: &mut [u8]) {
        self.render_rgb8_yuyv(img, &mut [], out);
    }

    /// [`Self::render_rgb8`] into `rgb` and [`Self::render_yuyv`] into
    /// `yuyv` in one pass with one auto range; an empty slice skips that output.
    pub fn render_rgb8_yuyv(&self, img: &Image<f32>, rgb: &mut [u8], yuyv: &mut [u8]) {
        self.render_rgb8_yuyv_with(Kernel::detect(), img, rgb, yuyv);
    }

    /// [`Self::render_rgb8_yuyv`] with the vector kernel, or none (the table
    /// path alone, as on CPUs without AVX-512 VBMI).
    fn render_rgb8_yuyv_with(
        &self,
        kernel: Option<Kernel>,
        img: &Image<f32>,
        rgb: &mut [u8],
        yuyv: &mut [u8],
    ) {
        let w = img.width.max(1);
        let n = img.data.len();
        let n_rgb = (rgb.len() / 3).min(n);
        if n_rgb == 0 && yuyv.len() < 4 {
            return;
        }
        let scale = 1.0 / self.max_abs_dn(img);
        let tables = Tables::get(self.colormap);
        let grey = self.colormap == Colormap::Grey;
        if let Some(k) = kernel {
            // Rows of whole 64-pixel steps and each output whole or absent:
            // the image is one run for the kernel, whose tables load once.
            let whole =
                |out: &[u8], bytes_per_px: usize| out.is_empty() || out.len() >= bytes_per_px * n;
            if w.is_multiple_of(KERNEL_STEP) && whole(rgb, 3) && whole(yuyv, 2) {
                let rgb = rgb.get_mut(..3 * n).unwrap_or_default();
                let yuyv = yuyv.get_mut(..2 * n).unwrap_or_default();
                if k.render(&tables.planes, grey, &img.data, scale, rgb, yuyv) == n {
                    return;
                }
            }
        }
        let mut idx = [0u16; BLOCK];
        for (y, row) in img.data.chunks(w).enumerate() {
            // Whole pairs of this row inside `yuyv`.
            let yuyv_row = yuyv.get_mut(2 * y * w..).unwrap_or_default();
            let pairs = (row.len() / 2).min(yuyv_row.len() / 4);
            for (b, block) in row.chunks(BLOCK).enumerate() {
                let x0 = b * BLOCK;
                let rgb_px = n_rgb.saturating_sub(y * w + x0).min(block.len());
                let rgb_out = &mut rgb[3 * (y * w + x0).min(n_rgb)..][..3 * rgb_px];
                let block_pairs = pairs.saturating_sub(x0 / 2).min(block.len() / 2);
                let yuyv_out = &mut yuyv_row[(2 * x0).min(4 * pairs)..][..4 * block_pairs];
                // The kernel takes the block's whole 64-pixel steps when each
                // output it writes holds all of them.
                let done = match kernel {
                    Some(k)
                        if (rgb_px == 0 || rgb_px == block.len())
                            && (block_pairs == 0 || block_pairs == block.len() / 2) =>
                    {
                        k.render(&tables.planes, grey, block, scale, rgb_out, yuyv_out)
                    }
                    _ => 0,
                };
                let block = &block[done..];
                let rgb_out = rgb_out.get_mut(3 * done..).unwrap_or_default();
                let yuyv_out = yuyv_out.get_mut(2 * done..).unwrap_or_default();
                let rgb_px = rgb_px.saturating_sub(done);
                let block_pairs = block_pairs.saturating_sub(done / 2);
                let idx = &mut idx[..block.len()];
                lut_indices(block, scale, idx);
                if rgb_px == 2 * block_pairs && rgb_px == idx.len() {
                    rgb_yuyv_pairs(tables, idx, rgb_out, yuyv_out);
                } else {
                    rgb_pixels(tables, idx, rgb_out);
                    yuyv_pairs(tables, idx, yuyv_out);
                }
            }
        }
    }

    /// Writes 3 bytes per pixel for a mode's output: the separated channels
    /// as colour when the output has them ([`render_channels_rgb8`]), else the
    /// signed image through the colormap ([`Self::render_rgb8`]).
    pub fn render_output_rgb8(&self, output: &ModeOutput, out: &mut [u8]) {
        match &output.channels {
            Some(ch) => render_channels_rgb8(ch, out),
            None => self.render_rgb8(&output.signed_dn, out),
        }
    }

    /// Writes the BT.601 full-range Y, U and V planes (the y4m stream's
    /// C444) of the colormapped image: the bytes
    /// [`crate::view::rgb8_to_yuv444_planes`] makes of
    /// [`Self::render_rgb8`]'s output. Pixels beyond the shortest plane are
    /// skipped.
    pub fn render_yuv444(&self, img: &Image<f32>, y: &mut [u8], u: &mut [u8], v: &mut [u8]) {
        let n = img.data.len().min(y.len()).min(u.len()).min(v.len());
        if n == 0 {
            return;
        }
        let scale = 1.0 / self.max_abs_dn(img);
        let tables = Tables::get(self.colormap);
        let mut idx = [0u16; BLOCK];
        let planes = y[..n]
            .chunks_mut(BLOCK)
            .zip(u[..n].chunks_mut(BLOCK))
            .zip(v[..n].chunks_mut(BLOCK));
        for (((y, u), v), values) in planes.zip(img.data.chunks(BLOCK)) {
            let idx = &mut idx[..values.len()];
            lut_indices(values, scale, idx);
            yuv_pixels(tables, idx, y, u, v);
        }
    }

    /// [`Self::render_output_rgb8`] as Y, U and V planes
    /// ([`render_channels_yuv444`] or [`Self::render_yuv444`]).
    pub fn render_output_yuv444(
        &self,
        output: &ModeOutput,
        y: &mut [u8],
        u: &mut [u8],
        v: &mut [u8],
    ) {
        match &output.channels {
            Some(ch) => render_channels_yuv444(ch, y, u, v),
            None => self.render_yuv444(&output.signed_dn, y, u, v),
        }
    }

    /// Writes 1 byte per pixel: the grey scale, whatever the colormap.
    pub fn render_grey8(&self, img: &Image<f32>, out: &mut [u8]) {
        let scale = 1.0 / self.max_abs_dn(img);
        grey_levels(&img.data, scale, out);
    }
}

/// v / max in [-1, 1]; NaN maps to 0 (neutral), +-Inf to the ends.
#[inline(always)]
fn normalized(v: f32, scale: f32) -> f32 {
    let t = v * scale;
    if t.is_nan() {
        0.0
    } else {
        t.clamp(-1.0, 1.0)
    }
}

/// `x.round() as u32` for x in [0, 2^22]: floor(x + ROUND_BIAS) is an exact
/// integer, and adding 2^23 puts it in the low mantissa bits. Unlike the
/// saturating `as` casts, this vectorizes (SSE4.1 and up).
#[inline(always)]
fn small_uint(x: f32) -> u32 {
    ((x + ROUND_BIAS).floor() + 8_388_608.0).to_bits() & 0x003f_ffff
}

/// Table index of each value: round((t + 1) * 511) for t = v * scale in [-1, 1].
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn lut_indices(values: &[f32], scale: f32, idx: &mut [u16]) {
    for (i, &v) in idx.iter_mut().zip(values) {
        *i = small_uint((normalized(v, scale) + 1.0) * LUT_HALF) as u16;
    }
}

/// Table colours of `idx` as packed RGB8; 4 pixels per 12-byte store group.
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn rgb_pixels(tables: &Tables, idx: &[u16], out: &mut [u8]) {
    let px = |i: u16| tables.rgb[usize::from(i) & 1023];
    let done = out.len() / 12 * 4;
    let mut quads = out.chunks_exact_mut(12);
    for (o, q) in (&mut quads).zip(idx.chunks_exact(4)) {
        let (a, b, c, d) = (px(q[0]), px(q[1]), px(q[2]), px(q[3]));
        let lo = u64::from(a) | u64::from(b) << 24 | u64::from(c) << 48;
        let hi = c >> 16 | d << 8;
        o[..8].copy_from_slice(&lo.to_le_bytes());
        o[8..].copy_from_slice(&hi.to_le_bytes());
    }
    for (o, &i) in quads
        .into_remainder()
        .chunks_exact_mut(3)
        .zip(&idx[done.min(idx.len())..])
    {
        o.copy_from_slice(&px(i).to_le_bytes()[..3]);
    }
}

/// Table colours of `idx` as Y, U and V planes (see [`Tables::yuv`]).
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn yuv_pixels(tables: &Tables, idx: &[u16], y: &mut [u8], u: &mut [u8], v: &mut [u8]) {
    for (((&i, y), u), v) in idx.iter().zip(y).zip(u).zip(v) {
        let [py, pu, pv, _] = tables.yuv[usize::from(i) & 1023].to_le_bytes();
        (*y, *u, *v) = (py, pu, pv);
    }
}

/// YUYV of pixel pairs of `idx` (see [`Tables::first`]).
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn yuyv_pairs(tables: &Tables, idx: &[u16], out: &mut [u8]) {
    for (o, p) in out.chunks_exact_mut(4).zip(idx.chunks_exact(2)) {
        let (i0, i1) = (usize::from(p[0]) & 1023, usize::from(p[1]) & 1023);
        let word = yuyv_word(tables.first[i0] + tables.second[i1]);
        o.copy_from_slice(&word.to_le_bytes());
    }
}

/// Both outputs of whole pixel pairs: `rgb` holds 6 and `yuyv` 4 bytes per
/// pair of `idx`. Each pair's RGB goes out as one 8-byte store that the next
/// pair overwrites in part.
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn rgb_yuyv_pairs(tables: &Tables, idx: &[u16], rgb: &mut [u8], yuyv: &mut [u8]) {
    for (j, (p, o)) in idx
        .chunks_exact(2)
        .zip(yuyv.chunks_exact_mut(4))
        .enumerate()
    {
        let (i0, i1) = (usize::from(p[0]) & 1023, usize::from(p[1]) & 1023);
        let six = u64::from(tables.rgb[i0]) | u64::from(tables.rgb[i1]) << 24;
        match rgb.get_mut(6 * j..6 * j + 8) {
            Some(d) => d.copy_from_slice(&six.to_le_bytes()),
            None => {
                let d = &mut rgb[6 * j..];
                let len = d.len().min(6);
                d[..len].copy_from_slice(&six.to_le_bytes()[..len]);
            }
        }
        let word = yuyv_word(tables.first[i0] + tables.second[i1]);
        o.copy_from_slice(&word.to_le_bytes());
    }
}

/// Grey level of each value: round((t + 1) * 127.5), zero at 128.
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
fn grey_levels(values: &[f32], scale: f32, out: &mut [u8]) {
    for (o, &v) in out.iter_mut().zip(values) {
        *o = small_uint((normalized(v, scale) + 1.0) * 127.5) as u8;
    }
}

/// Bits of |x| above this shift select a coarse bin (exponent and 3 mantissa bits).
const COARSE_SHIFT: u32 = 20;
/// The next 11 bits select a fine bin inside the coarse one.
const FINE_SHIFT: u32 = 9;
const BINS: usize = 2048;
/// Coarse bins from here on hold Inf and NaN.
const NON_FINITE_BIN: usize = (f32::INFINITY.to_bits() >> COARSE_SHIFT) as usize;
/// Coarse bins below this hold only zeros and subnormals.
const NORMAL_BIN: usize = (f32::MIN_POSITIVE.to_bits() >> COARSE_SHIFT) as usize;

/// The [`AUTO_PERCENTILE`] quantile of |x| over finite values; falls back to
/// the largest finite |x| when that is 0, and to 1 for an image with no
/// finite non-zero value. Never 0, NaN or Inf. One allocation (a subsample
/// of at most len / 16 values) brackets it for one counting pass; when the
/// bracket misses, histograms over the f32 bit pattern (monotonic for
/// x >= 0). Either way the result is the same sample, within 2^-14
/// (relative) above the exact quantile.
pub fn robust_max_abs(data: &[f32]) -> f32 {
    sampled_quantile(data).unwrap_or_else(|| histogram_quantile(data))
}

/// Every this many values (at least) feed the guess of where the quantile lies.
const SAMPLE_STRIDE: usize = 16;
/// Fewest values in that subsample (when the image has them): fewer, the
/// bracket widens and more values fall inside it.
const SAMPLE_MIN: usize = 4096;
/// The subsample holds at least (len / this)^2 values: then its bracket,
/// about 10 sqrt(0.005 / samples) of the image wide, keeps at most half of
/// [`WINDOW_CAPACITY`] values.
const SAMPLE_SCALE: usize = 5793;
/// Values near the guessed quantile kept for the exact count (on the stack).
const WINDOW_CAPACITY: usize = 8192;
/// Values per block of the counting pass (one maximum each), and lanes of
/// that maximum.
const COUNT_BLOCK: usize = 16;
const LANES: usize = 8;
/// |x| bits of +Inf: finite values lie below.
const INF_BITS: u32 = 0x7f80_0000;

/// The same result as [`histogram_quantile`], faster on large images: a
/// subsample brackets the quantile between two |x| bit patterns (aligned to
/// fine bins, so a fine bin is wholly in or out), one vectorized pass counts
/// the finite values and those below the bracket (by counting the rare ones
/// that are not, in the blocks whose maximum reaches the bracket) and keeps
/// the few inside it, and selection among
/// those finds the quantile's fine bin. None (use the
/// full histogram) when the bracket misses the quantile or holds more than
/// [`WINDOW_CAPACITY`] values, or the quantile is 0 or subnormal. The
/// counting pass is the AVX-512 kernel's where the CPU has it; no AVX-512
/// clone of the rest (it measured slower than AVX2 in the display bench).
#[multiversion(targets("x86_64+avx2", "x86_64+sse4.1"))]
fn sampled_quantile(data: &[f32]) -> Option<f32> {
    if data.len() < 64 * SAMPLE_STRIDE {
        return None;
    }
    // Copied once (one cache line of the image per value), so the
    // histograms below read a small contiguous buffer.
    let wanted = (data.len() / SAMPLE_SCALE)
        .saturating_pow(2)
        .max(SAMPLE_MIN);
    let stride = SAMPLE_STRIDE.max(data.len() / wanted);
    let mut sample: Vec<u32> = data
        .iter()
        .step_by(stride)
        .map(|v| v.to_bits() & 0x7fff_ffff)
        .collect();
    let finite = sample.iter().filter(|&&bits| bits < INF_BITS).count() as u64;
    if finite == 0 {
        return None;
    }
    let rank = ((AUTO_PERCENTILE * finite as f64).ceil() as u64).clamp(1, finite) - 1;
    // Five standard deviations of the subsample's count above the quantile.
    let margin = (5.0 * (finite as f64 * (1.0 - AUTO_PERCENTILE)).sqrt()) as u64 + 4;
    // The fine bins of the subsample's values of those ranks (non-finite
    // values sort last): selection, not histograms, over the small sample.
    let lo_rank = rank.saturating_sub(margin) as usize;
    let hi_rank = (rank + margin).min(finite - 1) as usize;
    let (_, &mut lo_value, above) = sample.select_nth_unstable(lo_rank);
    let hi_value = match hi_rank.checked_sub(lo_rank + 1) {
        Some(k) => *above.select_nth_unstable(k).1,
        None => lo_value,
    };
    let fine_bin = |bits: u32| bits >> FINE_SHIFT << FINE_SHIFT;
    let lo_bits = fine_bin(lo_value);
    let hi_bits = fine_bin(hi_value) + (1 << FINE_SHIFT);
    if lo_bits < f32::MIN_POSITIVE.to_bits() || hi_bits > INF_BITS {
        return None;
    }
    let mut window = [0u32; WINDOW_CAPACITY];
    let (finite, below, kept) = match Kernel::detect() {
        Some(k) => k.count_bracket(data, lo_bits, hi_bits, &mut window)?,
        None => count_bracket(data, lo_bits, hi_bits, &mut window)?,
    };
    let window = &mut window[..kept];
    let rank = ((AUTO_PERCENTILE * finite as f64).ceil() as u64).clamp(1, finite) - 1;
    if rank < below || rank >= below + kept as u64 {
        return None;
    }
    // The largest value sharing the quantile's fine bin, as the histogram finds it.
    let key = *window.select_nth_unstable((rank - below) as usize).1 >> FINE_SHIFT;
    let q = window
        .iter()
        .filter(|&&bits| bits >> FINE_SHIFT == key)
        .fold(0, |m, &bits| m.max(bits));
    Some(f32::from_bits(q))
}

/// One pass over `data`: how many |x| are finite, how many lie below
/// `lo_bits`, and the |x| bits in `lo_bits..hi_bits` copied into `window`
/// (their count is the third value); None when they overflow `window`.
#[multiversion(targets("x86_64+avx2", "x86_64+sse4.1"))]
fn count_bracket(
    data: &[f32],
    lo_bits: u32,
    hi_bits: u32,
    window: &mut [u32],
) -> Option<(u64, u64, usize)> {
    // Values at or above the bracket's bottom (the top percent or so, and
    // every NaN and Inf, whose |x| bits lie above any finite value's) are
    // rare: a block costs one vectorized maximum, and only blocks reaching
    // the bracket are looked at value by value. Then values below = all -
    // at or above, finite = all - non-finite.
    let (mut at_or_above, mut non_finite) = (0u64, 0u64);
    let mut kept = 0usize;
    let mut count = |block: &[f32]| -> Option<()> {
        for v in block {
            let bits = v.to_bits() & 0x7fff_ffff;
            if bits >= lo_bits {
                at_or_above += 1;
                non_finite += u64::from(bits >= INF_BITS);
                if bits < hi_bits {
                    *window.get_mut(kept)? = bits;
                    kept += 1;
                }
            }
        }
        Some(())
    };
    let mut blocks = data.chunks_exact(COUNT_BLOCK);
    for block in &mut blocks {
        let mut top = [0u32; LANES];
        for part in block.chunks_exact(LANES) {
            for (t, v) in top.iter_mut().zip(part) {
                *t = (*t).max(v.to_bits() & 0x7fff_ffff);
            }
        }
        if top.iter().fold(0, |m, &t| m.max(t)) >= lo_bits {
            count(block)?;
        }
    }
    count(blocks.remainder())?;
    let all = data.len() as u64;
    Some((all - non_finite, all - at_or_above, kept))
}

/// The two-pass histogram over all values (see [`robust_max_abs`]).
fn histogram_quantile(data: &[f32]) -> f32 {
    // Neighbouring pixels often share a bin: four interleaved histograms
    // keep consecutive increments independent. Non-finite values are
    // counted too, in bins >= NON_FINITE_BIN, and ignored.
    let mut coarse4 = [[0u32; BINS]; 4];
    let mut quads = data.chunks_exact(4);
    for q in &mut quads {
        for (h, &v) in coarse4.iter_mut().zip(q) {
            h[coarse_bin(v)] += 1;
        }
    }
    for &v in quads.remainder() {
        coarse4[0][coarse_bin(v)] += 1;
    }
    let mut coarse = [0u32; BINS];
    for (i, c) in coarse.iter_mut().enumerate() {
        *c = coarse4.iter().map(|h| h[i]).sum();
    }
    let finite: u64 = coarse[..NON_FINITE_BIN].iter().map(|&n| u64::from(n)).sum();
    if finite == 0 {
        return 1.0;
    }
    // 0-based rank of the quantile among the sorted finite |x|.
    let rank = ((AUTO_PERCENTILE * finite as f64).ceil() as u64).clamp(1, finite) - 1;
    let (bin, below) = find_bin(&coarse, rank);
    if bin < NORMAL_BIN {
        // The quantile is 0 or subnormal: the largest finite |x|, or 1 if 0.
        let max_abs = data
            .iter()
            .filter(|v| v.is_finite())
            .fold(0.0f32, |m, v| m.max(v.abs()));
        return if max_abs == 0.0 { 1.0 } else { max_abs };
    }
    let mut fine = [0u32; BINS];
    let mut fine_max_bits = [0u32; BINS];
    for &v in data {
        let bits = v.to_bits() & 0x7fff_ffff;
        if (bits >> COARSE_SHIFT) as usize == bin {
            let i = ((bits & ((1 << COARSE_SHIFT) - 1)) >> FINE_SHIFT) as usize;
            fine[i] += 1;
            fine_max_bits[i] = fine_max_bits[i].max(bits);
        }
    }
    // The largest value sharing the quantile's fine bin: a real sample.
    f32::from_bits(fine_max_bits[find_bin(&fine, rank - below).0])
}

#[inline(always)]
fn coarse_bin(v: f32) -> usize {
    ((v.to_bits() & 0x7fff_ffff) >> COARSE_SHIFT) as usize
}

/// The bin holding the element of 0-based `rank`, and how many lie below it.
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

#[cfg(test)]
mod tests {
    use super::*;

    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};

    /// Signed images with the awkward values: NaN, +-Inf, zeros, subnormals,
    /// huge outliers, exact half steps of the table.
    fn test_images() -> Vec<Image<f32>> {
        let mut rng = SmallRng::seed_from_u64(18);
        let mut imgs = Vec::new();
        for (w, h) in [(640, 480), (37, 5), (1, 9), (64, 3)] {
            let mut data: Vec<f32> = (0..w * h)
                .map(|_| rng.random_range(-1.0f32..1.0).powi(3) * 900.0)
                .collect();
            for (k, v) in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, 1e30]
                .into_iter()
                .enumerate()
            {
                let n = data.len();
                if k < n {
                    data[(k * 7919) % n] = v;
                }
            }
            imgs.push(Image::from_vec(w, h, data).unwrap());
        }
        // Every table step and half step for a fixed range of 511 DN.
        let steps: Vec<f32> = (-1100..=1100).map(|i| i as f32 * 0.5).collect();
        imgs.push(Image::from_vec(steps.len(), 1, steps).unwrap());
        imgs.push(Image::from_vec(4, 2, vec![f32::MIN_POSITIVE * 0.25; 8]).unwrap());
        // 1x1, all zero (the auto range falls back to 1), the f32 extremes.
        imgs.push(Image::from_vec(1, 1, vec![-3.0]).unwrap());
        imgs.push(Image::from_vec(5, 3, vec![0.0; 15]).unwrap());
        let extremes = vec![f32::MAX, -f32::MAX, f32::MIN_POSITIVE, -1e-45, 7.0];
        imgs.push(Image::from_vec(5, 1, extremes).unwrap());
        imgs.push(Image::from_vec(3, 1, vec![0.0, f32::NAN, 0.0]).unwrap());
        // The subsample sees only the outliers, or misses all of them, or
        // most values are NaN: the bracket misses and the full histogram answers.
        for (phase, big, nan_every) in [(0, 1e4, 0), (1, 1e4, 0), (3, 50.0, 3)] {
            let data: Vec<f32> = (0..64 * 48)
                .map(|i| match i % 16 {
                    _ if nan_every > 0 && i % nan_every != 0 => f32::NAN,
                    p if p == phase => big,
                    _ => (i % 97) as f32 * 0.25 - 12.0,
                })
                .collect();
            imgs.push(Image::from_vec(64, 48, data).unwrap());
        }
        // Many values tied at the quantile: more than the bracket's capacity.
        imgs.push(Image::from_vec(200, 100, vec![3.5; 20_000]).unwrap());
        imgs
    }

    fn maps() -> Vec<DisplayMap> {
        let mut v = Vec::new();
        for c in [Colormap::Diverging, Colormap::Grey] {
            for r in [
                DisplayRange::SymmetricAuto,
                DisplayRange::Fixed { max_abs_dn: 511.0 },
                DisplayRange::Fixed { max_abs_dn: 3.7 },
            ] {
                v.push(DisplayMap::new(c, r));
            }
        }
        v
    }

    #[test]
    fn fast_path_is_byte_identical_to_the_reference() {
        for img in test_images() {
            let n = img.data.len();
            assert_eq!(
                robust_max_abs(&img.data).to_bits(),
                reference::robust_max_abs(&img.data).to_bits()
            );
            for map in maps() {
                let (mut fast, mut slow) = (vec![1u8; 3 * n], vec![2u8; 3 * n]);
                map.render_rgb8(&img, &mut fast);
                reference::render_rgb8(&map, &img, &mut slow);
                assert_eq!(fast, slow, "{map:?} {}x{}", img.width, img.height);
                let (mut fast, mut slow) = (vec![1u8; n], vec![2u8; n]);
                map.render_grey8(&img, &mut fast);
                reference::render_grey8(&map, &img, &mut slow);
                assert_eq!(fast, slow, "{map:?}");
                // YUYV: the scalar packing of the reference RGB, row by row.
                let mut want = vec![7u8; 2 * n];
                for (s, d) in slow_rgb(&map, &img)
                    .chunks(3 * img.width)
                    .zip(want.chunks_mut(2 * img.width))
                {
                    crate::view::rgb_row_to_yuyv(s, d);
                }
                let (mut rgb, mut yuyv) = (vec![0u8; 3 * n], vec![7u8; 2 * n]);
                map.render_rgb8_yuyv(&img, &mut rgb, &mut yuyv);
                assert_eq!(yuyv, want, "{map:?} {}x{}", img.width, img.height);
                assert_eq!(rgb, slow_rgb(&map, &img));
                // The table path alone (CPUs without the AVX-512 kernel).
                let (mut rgb, mut yuyv) = (vec![0u8; 3 * n], vec![7u8; 2 * n]);
                map.render_rgb8_yuyv_with(None, &img, &mut rgb, &mut yuyv);
                assert_eq!(yuyv, want, "{map:?} {}x{} no kernel", img.width, img.height);
                assert_eq!(rgb, slow_rgb(&map, &img));
                // The y4m planes: those of the reference RGB.
                let (mut got, mut want) = (vec![1; 3 * n], vec![2; 3 * n]);
                let [y, u, v] = crate::view::yuv444_planes_mut(&mut want);
                crate::view::rgb8_to_yuv444_planes(&slow_rgb(&map, &img), y, u, v);
                let [y, u, v] = crate::view::yuv444_planes_mut(&mut got);
                map.render_yuv444(&img, y, u, v);
                assert!(got == want, "{map:?} {}x{} yuv444", img.width, img.height);
            }
        }
    }

    fn slow_rgb(map: &DisplayMap, img: &Image<f32>) -> Vec<u8> {
        let mut v = vec![0u8; 3 * img.data.len()];
        reference::render_rgb8(map, img, &mut v);
        v
    }

    #[test]
    fn short_outputs_write_only_what_fits() {
        let img = Image::from_vec(6, 2, (0..12).map(|i| i as f32 - 6.0).collect()).unwrap();
        let map = DisplayMap::default();
        let mut full = vec![0u8; 24];
        map.render_yuyv(&img, &mut full);
        let mut short = vec![9u8; 14];
        map.render_yuyv(&img, &mut short);
        assert_eq!(&short[..12], &full[..12]);
        assert_eq!(&short[12..], &[9, 9]);
        let mut rgb = vec![9u8; 7];
        map.render_rgb8(&img, &mut rgb);
        assert_eq!(&rgb[..6], &slow_rgb(&map, &img)[..6]);
        assert_eq!(rgb[6], 9);
    }

    /// The AVX-512 kernel runs wherever the CPU has the features it needs
    /// (so the tests above ran it on such a host), and equals the table path
    /// for every table index, NaN and +-Inf, with either output or both.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx512_kernel_equals_the_table_path() {
        let has = |f: &[bool]| f.iter().all(|&b| b);
        let expected = has(&[
            std::arch::is_x86_feature_detected!("avx512f"),
            std::arch::is_x86_feature_detected!("avx512bw"),
            std::arch::is_x86_feature_detected!("avx512vl"),
            std::arch::is_x86_feature_detected!("avx512vbmi"),
            std::arch::is_x86_feature_detected!("avx512vbmi2"),
            std::arch::is_x86_feature_detected!("avx512bitalg"),
            std::arch::is_x86_feature_detected!("avx512vnni"),
            std::arch::is_x86_feature_detected!("avx512vpopcntdq"),
            std::arch::is_x86_feature_detected!("gfni"),
            std::arch::is_x86_feature_detected!("vaes"),
            std::arch::is_x86_feature_detected!("vpclmulqdq"),
        ]);
        let Some(kernel) = Kernel::detect() else {
            assert!(
                !expected,
                "the CPU has the kernel's features but it was not detected"
            );
            eprintln!("no AVX-512 VBMI: kernel not tested on this host");
            return;
        };
        // Every index and half step at scale 1/511, then the awkward values.
        let mut values: Vec<f32> = (-1100..=1100).map(|i| i as f32 * 0.5).collect();
        values.extend([
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            1e30,
            -1e-45,
        ]);
        values.resize(values.len().next_multiple_of(KERNEL_STEP), -7.25);
        let n = values.len();
        for colormap in [Colormap::Diverging, Colormap::Grey] {
            let tables = Tables::get(colormap);
            let grey = colormap == Colormap::Grey;
            for scale in [1.0 / 511.0, 1.0 / 3.7, 1e-30] {
                let mut idx = vec![0u16; n];
                lut_indices(&values, scale, &mut idx);
                let (mut want_rgb, mut want_yuyv) = (vec![0u8; 3 * n], vec![0u8; 2 * n]);
                rgb_pixels(tables, &idx, &mut want_rgb);
                yuyv_pairs(tables, &idx, &mut want_yuyv);
                let (mut rgb, mut yuyv) = (vec![1u8; 3 * n], vec![1u8; 2 * n]);
                assert_eq!(
                    kernel.render(&tables.planes, grey, &values, scale, &mut rgb, &mut yuyv),
                    n
                );
                assert_eq!(rgb, want_rgb, "{colormap:?} {scale}");
                assert_eq!(yuyv, want_yuyv, "{colormap:?} {scale}");
                let mut rgb = vec![2u8; 3 * n];
                assert_eq!(
                    kernel.render(&tables.planes, grey, &values, scale, &mut rgb, &mut []),
                    n
                );
                assert_eq!(rgb, want_rgb);
                let mut yuyv = vec![2u8; 2 * n];
                assert_eq!(
                    kernel.render(&tables.planes, grey, &values, scale, &mut [], &mut yuyv),
                    n
                );
                assert_eq!(yuyv, want_yuyv);
                // A short output limits the steps done.
                let mut short = vec![3u8; 3 * n - 1];
                let done = kernel.render(&tables.planes, grey, &values, scale, &mut short, &mut []);
                assert_eq!(done, n - KERNEL_STEP);
                assert_eq!(short[..3 * done], want_rgb[..3 * done]);
            }
        }
        // The counting pass: same counts and kept values (in any order) as
        // the portable one, which the next test holds to the definition.
        let data = counting_data();
        for (lo, hi) in COUNTING_BRACKETS {
            let (lo, hi) = (lo.to_bits(), hi.to_bits());
            let (mut a, mut b) = ([0u32; WINDOW_CAPACITY], [0u32; WINDOW_CAPACITY]);
            let fast = kernel.count_bracket(&data, lo, hi, &mut a);
            let slow = count_bracket(&data, lo, hi, &mut b);
            match (fast, slow) {
                (Some(f), Some(s)) => {
                    assert_eq!(f, s, "{lo} {hi}");
                    let (a, b) = (&mut a[..f.2], &mut b[..s.2]);
                    a.sort_unstable();
                    b.sort_unstable();
                    assert_eq!(a, b);
                }
                // The kernel gives up a step early when the window is nearly full.
                (None, s) => assert!(s.is_none_or(|s| s.2 + 16 > WINDOW_CAPACITY)),
                (Some(_), None) => panic!("the kernel kept more than the window holds"),
            }
        }
    }

    /// Brackets of the counting tests, in |x|: the first's ends occur
    /// exactly in [`counting_data`], the last holds NaN and Inf above it.
    const COUNTING_BRACKETS: [(f32, f32); 5] = [
        (100.0, 101.0),
        (0.5, 2.0),
        (800.0, 900.0),
        (1e-3, 1e3),
        (800.0, 1e38),
    ];

    /// Values for the counting pass: NaN and +-Inf (at or above any
    /// bracket), -0, values exactly at the first bracket's ends, a run of
    /// 64-value steps whose only value reaching it is exactly its bottom,
    /// and a partial step at the end.
    fn counting_data() -> Vec<f32> {
        let mut rng = SmallRng::seed_from_u64(26);
        let mut data: Vec<f32> = (0..10_007)
            .map(|_| rng.random_range(-1.0f32..1.0).powi(3) * 900.0)
            .collect();
        data[1024..1280].fill(0.25);
        data[1100] = 100.0;
        data[1200] = -100.0;
        for (k, v) in [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            101.0,
            -100.0,
        ]
        .into_iter()
        .enumerate()
        {
            data[k * 1597 + 3] = v;
        }
        data[10_003] = f32::NAN; // in the partial step
        data
    }

    /// The portable counting pass (every host's, the VM's too) against the
    /// plain definition; None when more lie inside the bracket than the
    /// window holds.
    #[test]
    fn counting_pass_counts_as_defined() {
        let data = counting_data();
        for (lo, hi) in COUNTING_BRACKETS {
            let (lo, hi) = (lo.to_bits(), hi.to_bits());
            let bits = data.iter().map(|v| v.to_bits() & 0x7fff_ffff);
            let finite = bits.clone().filter(|&b| b < INF_BITS).count() as u64;
            let below = bits.clone().filter(|&b| b < lo).count() as u64;
            let mut inside: Vec<u32> = bits.filter(|b| (lo..hi).contains(b)).collect();
            inside.sort_unstable();
            let mut window = [0u32; WINDOW_CAPACITY];
            let got = count_bracket(&data, lo, hi, &mut window);
            if inside.len() > WINDOW_CAPACITY {
                assert_eq!(got, None, "{lo} {hi}");
                continue;
            }
            assert_eq!(got, Some((finite, below, inside.len())), "{lo} {hi}");
            window[..inside.len()].sort_unstable();
            assert_eq!(window[..inside.len()], inside[..]);
        }
    }

    /// Full-width frames take the kernel in one run; short outputs there
    /// fall back to the row path and write only what fits.
    #[test]
    fn short_outputs_of_kernel_wide_frames() {
        let img = Image::from_vec(128, 3, (0..384).map(|i| i as f32 - 190.0).collect()).unwrap();
        let map = DisplayMap::default();
        let mut full = vec![0u8; 2 * 384];
        map.render_yuyv(&img, &mut full);
        let mut short = vec![9u8; 2 * 384 - 2];
        map.render_yuyv(&img, &mut short);
        assert_eq!(&short[..2 * 384 - 4], &full[..2 * 384 - 4]);
        assert_eq!(&short[2 * 384 - 4..], &[9, 9]);
        let mut rgb = vec![9u8; 3 * 384 - 1];
        map.render_rgb8(&img, &mut rgb);
        assert_eq!(&rgb[..3 * 383], &slow_rgb(&map, &img)[..3 * 383]);
        assert_eq!(&rgb[3 * 383..], &[9, 9]);
    }

    #[test]
    fn round_bias_matches_round_on_the_table_range() {
        // Every 7th f32 in [0, 1023], and every f32 within 64 ulps of each half step.
        let check = |x: f32| assert_eq!((x + ROUND_BIAS) as u16, x.round() as u16, "{x:e}");
        let mut b = 0u32;
        while b <= 1023f32.to_bits() {
            check(f32::from_bits(b));
            b += 7;
        }
        for k in 0..1023 {
            let h = (k as f32 + 0.5).to_bits();
            (h - 64..=h + 64).for_each(|b| check(f32::from_bits(b)));
        }
    }

    /// The subsample's bracket is sized so the fast path answers, with the
    /// full histogram's result, for images from 640x480 up to 4 Mpixel.
    #[test]
    fn sampled_quantile_answers_large_images() {
        let mut rng = SmallRng::seed_from_u64(7);
        for n in [640 * 480, 1280 * 960, 2048 * 2048] {
            let mut data: Vec<f32> = (0..n)
                .map(|_| rng.random_range(-1.0f32..1.0).powi(3) * 900.0)
                .collect();
            data[n / 3] = f32::NAN;
            data[n / 2] = f32::INFINITY;
            let fast = sampled_quantile(&data);
            assert_eq!(
                fast.map(f32::to_bits),
                Some(histogram_quantile(&data).to_bits()),
                "{n}"
            );
        }
    }

    #[test]
    fn percentile_matches_sorting() {
        let data: Vec<f32> = (0..1000).map(|i| (i as f32 - 500.0) * 0.37).collect();
        let mut abs: Vec<f32> = data.iter().map(|v| v.abs()).collect();
        abs.sort_by(f32::total_cmp);
        let exact = abs[(0.995f64 * 1000.0).ceil() as usize - 1];
        let q = robust_max_abs(&data);
        assert!((q - exact).abs() <= exact * 1e-3, "{q} vs {exact}");
    }

    #[test]
    fn parse_names() {
        assert_eq!("grey".parse(), Ok(Colormap::Grey));
        // One parser for the config, sdid, D-Bus and sdictl: "gray" too (issue 14).
        assert_eq!("gray".parse(), Ok(Colormap::Grey));
        assert_eq!(Colormap::Grey.name(), "grey");
        for bad in ["Grey", "GRAY", "jet", ""] {
            assert!(bad.parse::<Colormap>().is_err(), "{bad}");
        }
        assert_eq!("12.5".parse(), Ok(DisplayRange::Fixed { max_abs_dn: 12.5 }));
        for bad in ["0", "-3", "NaN", "inf", "x"] {
            assert!(bad.parse::<DisplayRange>().is_err(), "{bad}");
        }
    }
}
