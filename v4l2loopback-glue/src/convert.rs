//! Packing the pipeline's output (RGB8, grey8 or signed DN as f32, each with
//! its own stride) into the tightly packed output formats. Pure Rust, no I/O,
//! no allocation per frame: scratch planes live in [`Converter`].

use crate::format::{PixelFormat, Y16_ZERO_DN};
use crate::GlueError;

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

    fn check(&self, channels: usize, width: usize, height: usize) -> Result<(), GlueError> {
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
            return Err(GlueError::InputMismatch {
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

/// RGB to YUYV implementation (both are kept so the bench can compare).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum YuyvPath {
    /// Hand-written fixed-point loop.
    Scalar,
    /// yuvutils-rs (SSE/AVX): RGB -> planar 4:2:2 -> YUYV.
    Simd,
}

impl YuyvPath {
    /// The faster one on this CPU (measured at 640x480, `loopback_tool
    /// convert`): yuvutils 0.135 ms vs the loop 0.697 ms with AVX2, but
    /// 10.1 ms vs 2.9 ms in the TCG VM's SSE4.2-only CPU.
    pub fn fastest() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self::Simd;
        }
        Self::Scalar
    }
}

/// Converts into one output geometry; owns the scratch planes.
pub struct Converter {
    width: usize,
    height: usize,
    format: PixelFormat,
    yuyv_path: YuyvPath,
    /// grey8 (full range) -> BT.601 limited-range luma.
    limited_luma: [u8; 256],
    y_plane: Vec<u8>,
    u_plane: Vec<u8>,
    v_plane: Vec<u8>,
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

impl Converter {
    pub fn new(width: u32, height: u32, format: PixelFormat, yuyv_path: YuyvPath) -> Self {
        let (w, h) = (width as usize, height as usize);
        let simd = format == PixelFormat::Yuyv && yuyv_path == YuyvPath::Simd;
        let chroma = if simd { w.div_ceil(2) * h } else { 0 };
        Self {
            width: w,
            height: h,
            format,
            yuyv_path,
            limited_luma: std::array::from_fn(|g| to_limited(g as u8)),
            y_plane: vec![0; if simd { w * h } else { 0 }],
            u_plane: vec![0; chroma],
            v_plane: vec![0; chroma],
        }
    }

    fn dst_row<'d>(&self, dst: &'d mut [u8], y: usize) -> &'d mut [u8] {
        let bpl = self.width * self.format.bytes_per_pixel();
        &mut dst[y * bpl..(y + 1) * bpl]
    }

    fn check_dst(&self, dst: &[u8]) -> Result<(), GlueError> {
        let need = self.width * self.height * self.format.bytes_per_pixel();
        if dst.len() < need {
            return Err(GlueError::InputMismatch {
                expected: format!("{need} output bytes"),
                got: format!("{}", dst.len()),
            });
        }
        Ok(())
    }

    /// Packs interleaved RGB8.
    pub fn rgb8(&mut self, src: Src<'_, u8>, dst: &mut [u8]) -> Result<(), GlueError> {
        src.check(3, self.width, self.height)?;
        self.check_dst(dst)?;
        if self.format == PixelFormat::Yuyv && self.yuyv_path == YuyvPath::Simd {
            return self.rgb8_yuyv_simd(src, dst);
        }
        for y in 0..self.height {
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

    fn rgb8_yuyv_simd(&mut self, src: Src<'_, u8>, dst: &mut [u8]) -> Result<(), GlueError> {
        use yuvutils_rs::{
            BufferStoreMut, YuvConversionMode, YuvPackedImageMut, YuvPlanarImageMut, YuvRange,
            YuvStandardMatrix,
        };
        let (w, h) = (self.width as u32, self.height as u32);
        let cw = w.div_ceil(2);
        let simd_err = |e: yuvutils_rs::YuvError| GlueError::InputMismatch {
            expected: "a frame yuvutils accepts".into(),
            got: e.to_string(),
        };
        let mut planar = YuvPlanarImageMut {
            y_plane: BufferStoreMut::Borrowed(&mut self.y_plane),
            y_stride: w,
            u_plane: BufferStoreMut::Borrowed(&mut self.u_plane),
            u_stride: cw,
            v_plane: BufferStoreMut::Borrowed(&mut self.v_plane),
            v_stride: cw,
            width: w,
            height: h,
        };
        let rgb_len = (h as usize - 1) * src.stride + w as usize * 3;
        yuvutils_rs::rgb_to_yuv422(
            &mut planar,
            &src.data[..rgb_len],
            src.stride as u32,
            YuvRange::Limited,
            YuvStandardMatrix::Bt601,
            YuvConversionMode::Balanced,
        )
        .map_err(simd_err)?;
        let bytes = w as usize * h as usize * 2;
        let mut packed = YuvPackedImageMut {
            yuy: BufferStoreMut::Borrowed(&mut dst[..bytes]),
            yuy_stride: w * 2,
            width: w,
            height: h,
        };
        yuvutils_rs::yuv422_to_yuyv422(&mut packed, &planar.to_fixed()).map_err(simd_err)
    }

    /// Packs 8-bit grey (full range).
    pub fn grey8(&mut self, src: Src<'_, u8>, dst: &mut [u8]) -> Result<(), GlueError> {
        src.check(1, self.width, self.height)?;
        self.check_dst(dst)?;
        for y in 0..self.height {
            let s = src.row(y, 1);
            let lut = self.limited_luma;
            let d = self.dst_row(dst, y);
            grey_row(self.format, &lut, s, d);
        }
        Ok(())
    }

    /// Packs signed difference DN. Y16 keeps 16 bits (offset mapping, see
    /// [`PixelFormat::Y16`]); 8-bit outputs keep the high byte of that value,
    /// so 0 DN is mid-grey 128.
    pub fn signed_dn(&mut self, src: Src<'_, f32>, dst: &mut [u8]) -> Result<(), GlueError> {
        src.check(1, self.width, self.height)?;
        self.check_dst(dst)?;
        let lut = self.limited_luma;
        for y in 0..self.height {
            let s = src.row(y, 1);
            let format = self.format;
            let d = self.dst_row(dst, y);
            match format {
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
/// each horizontal pixel pair.
fn rgb_row_to_yuyv(s: &[u8], d: &mut [u8]) {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn conv(f: PixelFormat, w: u32, h: u32) -> Converter {
        Converter::new(w, h, f, YuyvPath::Scalar)
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
    fn rgb_to_yuyv_known_colours_and_simd_agrees() {
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
                                 // SIMD path within 2 codes of the scalar one on a gradient
        let (w, h) = (64usize, 8usize);
        let grad: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 256) as u8).collect();
        let mut a = vec![0u8; w * h * 2];
        let mut b = vec![0u8; w * h * 2];
        let src = Src::packed(&grad, w, h, 3);
        Converter::new(w as u32, h as u32, PixelFormat::Yuyv, YuyvPath::Scalar)
            .rgb8(src, &mut a)
            .unwrap();
        Converter::new(w as u32, h as u32, PixelFormat::Yuyv, YuyvPath::Simd)
            .rgb8(src, &mut b)
            .unwrap();
        let worst = a.iter().zip(&b).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
        assert!(worst <= 3, "SIMD and scalar YUYV differ by {worst}");
    }

    #[test]
    fn mismatched_input_is_a_typed_error() {
        let data = [0u8; 5];
        let mut out = [0u8; 8];
        let e = conv(PixelFormat::Grey, 2, 2).grey8(Src::packed(&data, 2, 3, 1), &mut out);
        assert!(matches!(e, Err(GlueError::InputMismatch { .. })));
        let e = conv(PixelFormat::Grey, 2, 2).grey8(
            Src {
                data: &data,
                width: 2,
                height: 2,
                stride: 4,
            },
            &mut out,
        );
        assert!(matches!(e, Err(GlueError::InputMismatch { .. })));
    }
}
