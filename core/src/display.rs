//! Display mapping of signed DN images to 8-bit pixels, called by sinks (not a
//! pipeline stage). Diverging: negative blue, zero near-white, positive red,
//! as in the paper's figures; or grey with zero at mid-grey. The range is
//! symmetric about zero, either fixed or taken from a high percentile of |x|
//! so a few outliers (hot pixels, saturation, NaN/Inf) do not wash it out.

use std::str::FromStr;

use crate::image::Image;
use crate::mode::{ModeOutput, SeparatedChannels};

/// Fraction of finite pixels whose |x| lies inside the auto range.
pub const AUTO_PERCENTILE: f64 = 0.995;

/// Colour scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Colormap {
    /// Negative blue, zero near-white, positive red.
    #[default]
    Diverging,
    /// Black (most negative) to white (most positive), zero mid-grey.
    Grey,
}

impl Colormap {
    pub const NAMES: &'static [&'static str] = &["diverging", "grey"];

    pub fn name(self) -> &'static str {
        match self {
            Colormap::Diverging => "diverging",
            Colormap::Grey => "grey",
        }
    }
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

impl FromStr for Colormap {
    type Err = DisplayParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "diverging" => Ok(Colormap::Diverging),
            "grey" => Ok(Colormap::Grey),
            _ => Err(DisplayParseError::Colormap(s.to_owned())),
        }
    }
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

/// Diverging anchors at t = -1, -0.5, 0, 0.5, 1 (a red-blue scale).
const DIVERGING: [[f32; 3]; 5] = [
    [33.0, 102.0, 172.0],
    [103.0, 169.0, 207.0],
    [247.0, 247.0, 247.0],
    [239.0, 138.0, 98.0],
    [178.0, 24.0, 43.0],
];

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
        // A lookup table over [-1, 1] (steps of 1/511, finer than 8-bit output).
        let mut lut = [[0u8; 3]; LUT_SIZE];
        for (i, c) in lut.iter_mut().enumerate() {
            let t = i as f32 / LUT_HALF - 1.0;
            *c = match self.colormap {
                Colormap::Diverging => diverging(t),
                Colormap::Grey => [grey(t); 3],
            };
        }
        let scale = 1.0 / self.max_abs_dn(img);
        for (px, &v) in out.chunks_exact_mut(3).zip(&img.data) {
            let t = normalized(v, scale);
            px.copy_from_slice(&lut[((t + 1.0) * LUT_HALF).round() as usize]);
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

    /// Writes 1 byte per pixel: the grey scale, whatever the colormap.
    pub fn render_grey8(&self, img: &Image<f32>, out: &mut [u8]) {
        let scale = 1.0 / self.max_abs_dn(img);
        for (px, &v) in out.iter_mut().zip(&img.data) {
            *px = grey(normalized(v, scale));
        }
    }
}

/// The bipolar colour reconstruction of separated channels (section 5.2):
/// R = I+, G = 0, B = I-, both on one scale (the robust maximum over both
/// channels) so their ratio survives; negative and NaN values show as 0.
pub fn render_channels_rgb8(ch: &SeparatedChannels, out: &mut [u8]) {
    let max =
        robust_max_abs(&ch.i_plus_electrons.data).max(robust_max_abs(&ch.i_minus_electrons.data));
    let scale = 255.0 / max;
    let to_u8 = |v: f32| (v * scale).clamp(0.0, 255.0).round() as u8;
    for ((px, &p), &m) in out
        .chunks_exact_mut(3)
        .zip(&ch.i_plus_electrons.data)
        .zip(&ch.i_minus_electrons.data)
    {
        // NaN * scale is NaN; clamp keeps NaN, and `as u8` maps it to 0.
        px[0] = to_u8(p);
        px[1] = 0;
        px[2] = to_u8(m);
    }
}

/// v / max in [-1, 1]; NaN maps to 0 (neutral), +-Inf to the ends.
#[inline]
fn normalized(v: f32, scale: f32) -> f32 {
    let t = v * scale;
    if t.is_nan() {
        0.0
    } else {
        t.clamp(-1.0, 1.0)
    }
}

#[inline]
fn grey(t: f32) -> u8 {
    ((t + 1.0) * 127.5).round() as u8
}

#[inline]
fn diverging(t: f32) -> [u8; 3] {
    let x = (t + 1.0) * 2.0; // 0..=4 across the anchors
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    let (a, b) = (DIVERGING[i], DIVERGING[i + 1]);
    std::array::from_fn(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
}

/// The [`AUTO_PERCENTILE`] quantile of |x| over finite values; falls back to
/// the largest finite |x| when that is 0, and to 1 for an image with no
/// finite non-zero value. Never 0, NaN or Inf. Allocation-free: two passes of
/// a histogram over the f32 bit pattern (monotonic for x >= 0); the result
/// is a sample within 2^-14 (relative) above the exact quantile.
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
    // 0-based rank of the quantile among the sorted finite |x|.
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
    // The largest value sharing the quantile's fine bin: a real sample.
    let q = fine_max[find_bin(&fine, rank - below).0];
    if q >= f32::MIN_POSITIVE {
        q
    } else {
        max_abs
    }
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
    fn channels_render_red_and_blue() {
        let img = |v: &[f32]| Image {
            width: v.len(),
            height: 1,
            data: v.to_vec(),
        };
        let ch = SeparatedChannels {
            i_plus_electrons: img(&[1000.0, 0.0, -5.0, f32::NAN]),
            i_minus_electrons: img(&[0.0, 500.0, 0.0, 0.0]),
        };
        let mut rgb = [9u8; 12];
        render_channels_rgb8(&ch, &mut rgb);
        assert_eq!(&rgb[0..3], &[255, 0, 0]);
        assert_eq!(&rgb[3..6], &[0, 0, 128]);
        assert_eq!(&rgb[6..12], &[0; 6]);
    }

    #[test]
    fn parse_names() {
        assert_eq!("grey".parse(), Ok(Colormap::Grey));
        assert!("gray".parse::<Colormap>().is_err());
        assert_eq!("12.5".parse(), Ok(DisplayRange::Fixed { max_abs_dn: 12.5 }));
        for bad in ["0", "-3", "NaN", "inf", "x"] {
            assert!(bad.parse::<DisplayRange>().is_err(), "{bad}");
        }
    }
}
