//! Packing rendered pixels (RGB8, grey8 or signed DN as f32, each with its
//! own stride) into the tightly packed published formats. The colour
//! conversions here are BT.601: limited range for YUYV (browsers' camera
//! format), full range for the y4m stream's 4:4:4 planes.

use multiversion::multiversion;

use super::{PixelFormat, Y16_ZERO_DN};

/// A source image or output buffer that does not have the packer's geometry.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("input does not match the output format: expected {expected}, got {got}")]
pub struct PackError {
    pub expected: String,
    pub got: String,
}

/// A borrowed source image; `stride` counts elements (bytes for `u8`).
#[derive(Clone, Copy, Debug)]
pub struct Src<'a, T> {
    pub data: &'a [T],
    pub width: usize,
    pub height: usize,
    pub stride: usize,
}

impl<'a, T> Src<'a, T> {
    /// A tightly packed image with `channels` elements per pixel.
    pub fn packed(data: &'a [T], width: usize, height: usize, channels: usize) -> Self {
        Self {
            data,
            width,
            height,
            stride: width * channels,
        }
    }

    fn check(&self, channels: usize, width: usize, height: usize) -> Result<(), PackError> {
        let row = self.width * channels;
        let needed = if self.height == 0 {
            0
        } else {
            (self.height - 1) * self.stride + row
        };
        if self.width != width
            || self.height != height
            || self.stride < row
            || self.data.len() < needed
        {
            return Err(PackError {
                expected: format!("{width}x{height} with stride >= {}", width * channels),
                got: format!(
                    "{}x{} stride {} ({} elements)",
                    self.width,
                    self.height,
                    self.stride,
                    self.data.len()
                ),
            });
        }
        Ok(())
    }

    fn row(&self, y: usize, channels: usize) -> &'a [T] {
        &self.data[y * self.stride..y * self.stride + self.width * channels]
    }
}

/// Packs into one output geometry and format.
#[derive(Clone, Debug)]
pub struct Packer {
    width: usize,
    height: usize,
    format: PixelFormat,
    /// grey8 (full range) -> BT.601 limited-range luma.
    limited_luma: [u8; 256],
}

/// Full-range grey -> limited range luma (16..=235).
fn to_limited(g: u8) -> u8 {
    (16 + (u32::from(g) * 219 + 127) / 255) as u8
}

/// BT.601 full-range luma of one RGB pixel.
#[inline]
fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((77 * u32::from(r) + 150 * u32::from(g) + 29 * u32::from(b) + 128) >> 8) as u8
}

/// Signed DN -> offset Y16 (see [`PixelFormat::Y16`]); NaN maps to 0 DN.
#[inline]
pub fn dn_to_y16(dn: f32) -> u16 {
    if dn.is_nan() {
        return Y16_ZERO_DN as u16;
    }
    // `as u16` saturates (negative -> 0, > 65535 -> 65535); +0.5 then
    // truncation rounds half up without a libm call, so the loop vectorizes.
    (dn + (Y16_ZERO_DN as f32 + 0.5)) as u16
}

impl Packer {
    pub fn new(width: usize, height: usize, format: PixelFormat) -> Self {
        Self {
            width,
            height,
            format,
            limited_luma: std::array::from_fn(|g| to_limited(g as u8)),
        }
    }

    pub fn format(&self) -> PixelFormat {
        self.format
    }

    /// Bytes of one packed frame.
    pub fn frame_bytes(&self) -> usize {
        self.width * self.height * self.format.bytes_per_pixel()
    }

    fn dst_row<'d>(&self, dst: &'d mut [u8], y: usize) -> &'d mut [u8] {
        let bpl = self.width * self.format.bytes_per_pixel();
        &mut dst[y * bpl..(y + 1) * bpl]
    }

    fn check_dst(&self, dst: &[u8]) -> Result<(), PackError> {
        let need = self.frame_bytes();
        if dst.len() < need {
            return Err(PackError {
                expected: format!("{need} output bytes"),
                got: format!("{}", dst.len()),
            });
        }
        Ok(())
    }

    /// Packs interleaved RGB8.
    pub fn rgb8(&self, src: Src<'_, u8>, dst: &mut [u8]) -> Result<(), PackError> {
        self.rgb8_rows(src, dst, |_| false)
    }

    /// [`Self::rgb8`] where `same_as_above(y)` says source row y repeats
    /// row y - 1 (a scaled image's repeated rows): its packed row is copied.
    pub fn rgb8_rows(
        &self,
        src: Src<'_, u8>,
        dst: &mut [u8],
        same_as_above: impl Fn(usize) -> bool,
    ) -> Result<(), PackError> {
        src.check(3, self.width, self.height)?;
        self.check_dst(dst)?;
        let bpl = self.width * self.format.bytes_per_pixel();
        for y in 0..self.height {
            if y > 0 && same_as_above(y) {
                dst.copy_within((y - 1) * bpl..y * bpl, y * bpl);
                continue;
            }
            let s = src.row(y, 3);
            let d = self.dst_row(dst, y);
            match self.format {
                PixelFormat::Rgb24 => d.copy_from_slice(s),
                PixelFormat::Grey => {
                    for (o, p) in d.iter_mut().zip(s.chunks_exact(3)) {
                        *o = luma(p[0], p[1], p[2]);
                    }
                }
                PixelFormat::Y16 => {
                    for (o, p) in d.chunks_exact_mut(2).zip(s.chunks_exact(3)) {
                        let v = u16::from(luma(p[0], p[1], p[2])) * 257;
                        o.copy_from_slice(&v.to_le_bytes());
                    }
                }
                PixelFormat::Yuyv => rgb_row_to_yuyv(s, d),
            }
        }
        Ok(())
    }

    /// Packs 8-bit grey (full range).
    pub fn grey8(&self, src: Src<'_, u8>, dst: &mut [u8]) -> Result<(), PackError> {
        src.check(1, self.width, self.height)?;
        self.check_dst(dst)?;
        self.pack_grey8(src, dst);
        Ok(())
    }

    /// [`Self::grey8`] for a source and output of the packer's geometry.
    pub(super) fn pack_grey8(&self, src: Src<'_, u8>, dst: &mut [u8]) {
        for y in 0..self.height {
            let s = src.row(y, 1);
            let d = self.dst_row(dst, y);
            grey_row(self.format, &self.limited_luma, s, d);
        }
    }

    /// Packs signed difference DN. Y16 keeps 16 bits (offset mapping, see
    /// [`PixelFormat::Y16`]); 8-bit outputs keep the high byte of that value,
    /// so 0 DN is mid-grey 128.
    pub fn signed_dn(&self, src: Src<'_, f32>, dst: &mut [u8]) -> Result<(), PackError> {
        src.check(1, self.width, self.height)?;
        self.check_dst(dst)?;
        let lut = &self.limited_luma;
        for y in 0..self.height {
            let s = src.row(y, 1);
            let d = self.dst_row(dst, y);
            match self.format {
                PixelFormat::Y16 => {
                    for (o, &v) in d.chunks_exact_mut(2).zip(s) {
                        o.copy_from_slice(&dn_to_y16(v).to_le_bytes());
                    }
                }
                PixelFormat::Grey => {
                    for (o, &v) in d.iter_mut().zip(s) {
                        *o = (dn_to_y16(v) >> 8) as u8;
                    }
                }
                PixelFormat::Rgb24 => {
                    for (o, &v) in d.chunks_exact_mut(3).zip(s) {
                        o.fill((dn_to_y16(v) >> 8) as u8);
                    }
                }
                PixelFormat::Yuyv => {
                    for (o, v) in d.chunks_exact_mut(4).zip(s.chunks_exact(2)) {
                        o[0] = lut[(dn_to_y16(v[0]) >> 8) as usize];
                        o[1] = 128;
                        o[2] = lut[(dn_to_y16(v[1]) >> 8) as usize];
                        o[3] = 128;
                    }
                }
            }
        }
        Ok(())
    }
}

fn grey_row(format: PixelFormat, lut: &[u8; 256], s: &[u8], d: &mut [u8]) {
    match format {
        PixelFormat::Grey => d.copy_from_slice(s),
        PixelFormat::Y16 => {
            for (o, &g) in d.chunks_exact_mut(2).zip(s) {
                o.copy_from_slice(&(u16::from(g) * 257).to_le_bytes());
            }
        }
        PixelFormat::Rgb24 => {
            for (o, &g) in d.chunks_exact_mut(3).zip(s) {
                o.fill(g);
            }
        }
        PixelFormat::Yuyv => {
            for (o, g) in d.chunks_exact_mut(4).zip(s.chunks_exact(2)) {
                o[0] = lut[g[0] as usize];
                o[1] = 128;
                o[2] = lut[g[1] as usize];
                o[3] = 128;
            }
        }
    }
}

/// One row of RGB8 to YUYV, BT.601 limited range, chroma from the mean of
/// each horizontal pixel pair. [`crate::display`]'s tables give the same
/// bytes for colormapped images without going through RGB (its tests hold
/// them to this function). Compiled for each vector width (multiversion):
/// the separated channels' 640x480 view packs through it every frame.
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
pub(crate) fn rgb_row_to_yuyv(s: &[u8], d: &mut [u8]) {
    for (o, p) in d.chunks_exact_mut(4).zip(s.chunks_exact(6)) {
        let (r0, g0, b0) = (i32::from(p[0]), i32::from(p[1]), i32::from(p[2]));
        let (r1, g1, b1) = (i32::from(p[3]), i32::from(p[4]), i32::from(p[5]));
        let y = |r: i32, g: i32, b: i32| (((66 * r + 129 * g + 25 * b + 128) >> 8) + 16) as u8;
        let (r, g, b) = (r0 + r1, g0 + g1, b0 + b1); // sums of two: shift by 9
        let u = (((-38 * r - 74 * g + 112 * b + 256) >> 9) + 128).clamp(0, 255) as u8;
        let v = (((112 * r - 94 * g - 18 * b + 256) >> 9) + 128).clamp(0, 255) as u8;
        o[0] = y(r0, g0, b0);
        o[1] = u;
        o[2] = y(r1, g1, b1);
        o[3] = v;
    }
}

/// BT.601 full-range RGB -> Y, U, V planes (the y4m stream's C444) in 16.16
/// fixed point: within one code of the float formula (tested on every
/// colour), and integer-only so it vectorizes (for each vector width).
#[multiversion(targets("x86_64+avx512f+avx512bw+avx512vl", "x86_64+avx2", "x86_64+sse4.1"))]
pub fn rgb8_to_yuv444_planes(rgb: &[u8], y: &mut [u8], u: &mut [u8], v: &mut [u8]) {
    for (((px, y), u), v) in rgb.chunks_exact(3).zip(y).zip(u).zip(v) {
        [*y, *u, *v] = yuv444_pixel(px[0], px[1], px[2]);
    }
}

/// The Y, U and V planes of a 4:4:4 frame (a third of it each).
pub fn yuv444_planes_mut(frame: &mut [u8]) -> [&mut [u8]; 3] {
    let n = frame.len() / 3;
    let (y, uv) = frame.split_at_mut(n);
    let (u, v) = uv[..2 * n].split_at_mut(n);
    [y, u, v]
}

/// One pixel of [`rgb8_to_yuv444_planes`]: Y, U, V of R, G, B.
#[inline(always)]
pub(crate) fn yuv444_pixel(r: u8, g: u8, b: u8) -> [u8; 3] {
    const HALF: i32 = 1 << 15;
    const OFFSET: i32 = 128 << 16;
    let (r, g, b) = (i32::from(r), i32::from(g), i32::from(b));
    // Coefficients x 65536: Y 0.299 0.587 0.114; U -0.168736 -0.331264
    // 0.5; V 0.5 -0.418688 -0.081312 (each row sums to 65536 or 0).
    [
        ((19595 * r + 38470 * g + 7471 * b + HALF) >> 16) as u8,
        ((-11059 * r - 21709 * g + 32768 * b + OFFSET + HALF) >> 16).clamp(0, 255) as u8,
        ((32768 * r - 27439 * g - 5329 * b + OFFSET + HALF) >> 16).clamp(0, 255) as u8,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn conv(f: PixelFormat, w: usize, h: usize) -> Packer {
        Packer::new(w, h, f)
    }

    #[test]
    fn grey_packs_every_format_and_honours_stride() {
        // 2x2 image inside a stride of 3 (padding byte 99 must be skipped)
        let data = [0u8, 255, 99, 128, 64, 99];
        let src = Src {
            data: &data,
            width: 2,
            height: 2,
            stride: 3,
        };
        let mut out = vec![0u8; 16];
        conv(PixelFormat::Grey, 2, 2).grey8(src, &mut out).unwrap();
        assert_eq!(&out[..4], &[0, 255, 128, 64]);
        conv(PixelFormat::Y16, 2, 2).grey8(src, &mut out).unwrap();
        assert_eq!(&out[..8], &[0, 0, 255, 255, 128, 128, 64, 64]);
        conv(PixelFormat::Yuyv, 2, 2).grey8(src, &mut out).unwrap();
        assert_eq!(&out[..8], &[16, 128, 235, 128, 126, 128, 71, 128]);
        let mut rgb = vec![0u8; 12];
        conv(PixelFormat::Rgb24, 2, 2).grey8(src, &mut rgb).unwrap();
        assert_eq!(&rgb[..6], &[0, 0, 0, 255, 255, 255]);
    }

    #[test]
    fn signed_dn_offset_mapping() {
        assert_eq!(dn_to_y16(0.0), 32768);
        assert_eq!(dn_to_y16(-32768.0), 0);
        assert_eq!(dn_to_y16(1e9), 65535);
        assert_eq!(dn_to_y16(-1e9), 0);
        assert_eq!(dn_to_y16(f32::NAN), 32768);
        assert_eq!(dn_to_y16(-1.4), 32767);
        let data = [-100.0f32, 100.0];
        let mut out = [0u8; 4];
        conv(PixelFormat::Y16, 2, 1)
            .signed_dn(Src::packed(&data, 2, 1, 1), &mut out)
            .unwrap();
        assert_eq!(u16::from_le_bytes([out[0], out[1]]), 32668);
        assert_eq!(u16::from_le_bytes([out[2], out[3]]), 32868);
    }

    #[test]
    fn rgb_to_yuyv_known_colours() {
        // white, black, red, blue pairs
        let px: [[u8; 3]; 4] = [[255, 255, 255], [255, 255, 255], [255, 0, 0], [255, 0, 0]];
        let data: Vec<u8> = px.iter().flatten().copied().collect();
        let mut out = [0u8; 8];
        conv(PixelFormat::Yuyv, 4, 1)
            .rgb8(Src::packed(&data, 4, 1, 3), &mut out)
            .unwrap();
        assert_eq!(out[0], 235);
        assert!((127..=129).contains(&out[1]));
        assert_eq!(out[4], 82); // red luma
        assert_eq!(out[7], 240); // red V
    }

    #[test]
    fn mismatched_input_is_a_typed_error() {
        let data = [0u8; 5];
        let mut out = [0u8; 8];
        assert!(conv(PixelFormat::Grey, 2, 2)
            .grey8(Src::packed(&data, 2, 3, 1), &mut out)
            .is_err());
        let strided = Src {
            data: &data,
            width: 2,
            height: 2,
            stride: 4,
        };
        assert!(conv(PixelFormat::Grey, 2, 2)
            .grey8(strided, &mut out)
            .is_err());
    }

    #[test]
    fn fixed_point_yuv444_is_within_one_code_of_bt601_for_every_colour() {
        let rgb: Vec<u8> = (0..1u32 << 24)
            .flat_map(|c| [c as u8, (c >> 8) as u8, (c >> 16) as u8])
            .collect();
        let n = rgb.len() / 3;
        let (mut y, mut u, mut v) = (vec![0; n], vec![0; n], vec![0; n]);
        rgb8_to_yuv444_planes(&rgb, &mut y, &mut u, &mut v);
        let mut worst = 0;
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            let (r, g, b) = (f32::from(px[0]), f32::from(px[1]), f32::from(px[2]));
            let fy = (0.299 * r + 0.587 * g + 0.114 * b).round();
            let fu = (128.0 - 0.168_736 * r - 0.331_264 * g + 0.5 * b)
                .round()
                .clamp(0.0, 255.0);
            let fv = (128.0 + 0.5 * r - 0.418_688 * g - 0.081_312 * b)
                .round()
                .clamp(0.0, 255.0);
            for (ours, float) in [(y[i], fy), (u[i], fu), (v[i], fv)] {
                worst = worst.max((f32::from(ours) - float).abs() as u32);
            }
        }
        assert!(worst <= 1, "worst difference {worst} codes");
        // Grey stays grey: U = V = 128 exactly.
        for g in 0..=255u8 {
            let (mut y, mut u, mut v) = ([0], [0], [0]);
            rgb8_to_yuv444_planes(&[g, g, g], &mut y, &mut u, &mut v);
            assert_eq!((y[0], u[0], v[0]), (g, 128, 128));
        }
    }
}
