//! [`ViewRenderer`]: a mode's output as the bytes of one published stream.

use super::letterbox::{letterbox_rgb8, source_index, LetterboxRect};
use super::pack::{rgb8_to_yuv444_planes, yuv444_planes_mut, PackError, Packer, Src};
use super::PixelFormat;
use crate::display::{DisplayMap, DisplayRange};
use crate::image::Image;
use crate::mode::ModeOutput;

/// YUYV of black (RGB 0, 0, 0 through BT.601 limited range).
const BLACK_YUYV: [u8; 4] = [16, 128, 16, 128];

/// Renders into one geometry and pixel format; owns every scratch buffer,
/// so a frame allocates nothing once the sizes have settled.
pub struct ViewRenderer {
    width: usize,
    height: usize,
    packer: Packer,
    /// The mode's rendering at the source size, and letterboxed.
    rgb: Vec<u8>,
    scaled: Vec<u8>,
    /// The direct YUYV path's scaled signed image and its YUYV.
    scaled_dn: Image<f32>,
    /// The source column of each scaled column.
    cols: Vec<usize>,
    content: Vec<u8>,
    /// The packed frame handed to the sink.
    frame: Vec<u8>,
}

impl ViewRenderer {
    pub fn new(width: usize, height: usize, format: PixelFormat) -> Self {
        Self {
            width,
            height,
            packer: Packer::new(width, height, format),
            rgb: Vec::new(),
            scaled: Vec::new(),
            scaled_dn: Image::new(0, 0),
            cols: Vec::new(),
            content: Vec::new(),
            frame: Vec::new(),
        }
    }

    pub fn format(&self) -> PixelFormat {
        self.packer.format()
    }

    /// The rendered frame's width, pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// The rendered frame's height, pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Bytes of one packed frame.
    pub fn frame_bytes(&self) -> usize {
        self.packer.frame_bytes()
    }

    /// The view of `output`: the separated channels as colour, or the signed
    /// image through `display`'s colormap, letterboxed into the output size
    /// and packed.
    pub fn render(
        &mut self,
        output: &ModeOutput,
        display: &DisplayMap,
    ) -> Result<&[u8], PackError> {
        let img = &output.signed_dn;
        let (w, h) = (img.width, img.height);
        let (dw, dh) = (self.width, self.height);
        self.frame.resize(self.packer.frame_bytes(), 0);
        if self.format() == PixelFormat::Yuyv && self.direct_yuyv(output, display) {
            return Ok(&self.frame);
        }
        if (w, h) == (dw, dh) && self.format() == PixelFormat::Rgb24 {
            display.render_output_rgb8(output, &mut self.frame);
            return Ok(&self.frame);
        }
        self.rgb.resize(w * h * 3, 0);
        display.render_output_rgb8(output, &mut self.rgb);
        self.scaled.resize(dw * dh * 3, 0);
        let rows = letterbox_rgb8(&self.rgb, w, h, &mut self.scaled, dw, dh);
        self.packer
            .rgb8_rows(Src::packed(&self.scaled, dw, dh, 3), &mut self.frame, |y| {
                rows[y] == rows[y - 1]
            })?;
        Ok(&self.frame)
    }

    /// The view of `output` as the y4m stream's C444 frame: the Y, U and V
    /// planes (BT.601 full range) one after the other, the bytes
    /// [`rgb8_to_yuv444_planes`] makes of the RGB24 view. Straight from the
    /// floats at the output size; letterboxed through RGB otherwise. The
    /// renderer's pixel format is not used.
    pub fn render_yuv444(&mut self, output: &ModeOutput, display: &DisplayMap) -> &[u8] {
        let img = &output.signed_dn;
        let (w, h) = (img.width, img.height);
        let n = self.width * self.height;
        self.frame.resize(3 * n, 0);
        let [y, u, v] = yuv444_planes_mut(&mut self.frame);
        if (w, h) == (self.width, self.height) {
            display.render_output_yuv444(output, y, u, v);
        } else {
            self.rgb.resize(w * h * 3, 0);
            display.render_output_rgb8(output, &mut self.rgb);
            self.scaled.resize(n * 3, 0);
            letterbox_rgb8(&self.rgb, w, h, &mut self.scaled, self.width, self.height);
            rgb8_to_yuv444_planes(&self.scaled, y, u, v);
        }
        &self.frame
    }

    /// The signed image itself, packed (a data stream: Y16 keeps the DN,
    /// see [`PixelFormat::Y16`]); its size must be the output size.
    pub fn render_signed_dn(&mut self, img: &Image<f32>) -> Result<&[u8], PackError> {
        self.frame.resize(self.packer.frame_bytes(), 0);
        self.packer.signed_dn(
            Src::packed(&img.data, img.width, img.height, 1),
            &mut self.frame,
        )?;
        Ok(&self.frame)
    }

    /// The YUYV frame of a signed image without separated channels, rendered
    /// straight to YUYV: the image scaled as [`letterbox_rgb8`] scales the
    /// RGB, colormapped with the original image's range by
    /// [`DisplayMap::render_yuyv`], black bars. The same bytes as the RGB
    /// path (render, letterbox, pack) at a quarter of its cost. False where
    /// pixel pairs would straddle a bar (odd bar or content width): the RGB
    /// path handles those.
    fn direct_yuyv(&mut self, output: &ModeOutput, display: &DisplayMap) -> bool {
        let img = &output.signed_dn;
        let (w, h) = (img.width, img.height);
        let (dw, dh) = (self.width, self.height);
        if output.channels.is_some() || w == 0 || h == 0 || img.data.len() != w * h {
            return false;
        }
        let r = LetterboxRect::new(w, h, dw, dh);
        let (x0, y0, sw, sh) = (r.x0, r.y0, r.width, r.height);
        if x0 % 2 != 0 || sw % 2 != 0 || sw == 0 || sh == 0 {
            return false;
        }
        // One range from the image itself (the scaled copy repeats pixels).
        let map = DisplayMap::new(
            display.colormap,
            DisplayRange::Fixed {
                max_abs_dn: display.max_abs_dn(img),
            },
        );
        // Each distinct source row is scaled and colormapped once; the
        // rows that repeat it (every other one when doubling) are copies.
        let rows: Vec<usize> = (0..sh).map(|y| source_index(y, h, sh)).collect();
        let mut distinct = rows.clone();
        distinct.dedup();
        if self.scaled_dn.width != sw || self.scaled_dn.height != distinct.len() {
            self.scaled_dn = Image::new(sw, distinct.len());
        }
        self.cols.clear();
        self.cols.extend((0..sw).map(|x| source_index(x, w, sw)));
        for (row, &sy) in self.scaled_dn.data.chunks_exact_mut(sw).zip(&distinct) {
            let src = &img.data[sy * w..][..w];
            for (d, &sx) in row.iter_mut().zip(&self.cols) {
                *d = src[sx];
            }
        }
        self.content.resize(sw * distinct.len() * 2, 0);
        map.render_yuyv(&self.scaled_dn, &mut self.content);
        self.frame.resize(dw * dh * 2, 0);
        if (sw, sh) != (dw, dh) {
            for px in self.frame.chunks_exact_mut(4) {
                px.copy_from_slice(&BLACK_YUYV);
            }
        }
        let mut k = 0;
        for y in 0..sh {
            if y > 0 && rows[y] != rows[y - 1] {
                k += 1;
            }
            let row = &self.content[k * sw * 2..][..sw * 2];
            self.frame[((y0 + y) * dw + x0) * 2..][..sw * 2].copy_from_slice(row);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::display::Colormap;

    /// The RGB path the direct YUYV view replaces: render, letterbox, pack.
    fn via_rgb(out: &ModeOutput, map: &DisplayMap, dw: usize, dh: usize) -> Vec<u8> {
        let img = &out.signed_dn;
        let mut rgb = vec![0u8; img.width * img.height * 3];
        map.render_output_rgb8(out, &mut rgb);
        let mut scaled = vec![0u8; dw * dh * 3];
        letterbox_rgb8(&rgb, img.width, img.height, &mut scaled, dw, dh);
        let mut yuyv = vec![0u8; dw * dh * 2];
        Packer::new(dw, dh, PixelFormat::Yuyv)
            .rgb8(Src::packed(&scaled, dw, dh, 3), &mut yuyv)
            .expect("pack");
        yuyv
    }

    #[test]
    fn direct_yuyv_view_matches_the_rgb_path() {
        // Full-width 2x (the boards' 320x240), side bars, top and bottom
        // bars, the view size itself, halving and a scale of 3.2.
        for (w, h) in [
            (320, 240),
            (240, 240),
            (320, 120),
            (64, 48),
            (640, 480),
            (1280, 960),
            (200, 150),
        ] {
            let data = (0..w * h)
                .map(|i| match i % 97 {
                    0 => f32::NAN,
                    1 => 1e6,
                    k => (k as f32 - 48.0) * 7.5 + (i / w) as f32,
                })
                .collect();
            let mut out = ModeOutput::new(w, h);
            out.signed_dn = Image {
                width: w,
                height: h,
                data,
            };
            for colormap in [Colormap::Diverging, Colormap::Grey] {
                for range in [
                    DisplayRange::SymmetricAuto,
                    DisplayRange::Fixed { max_abs_dn: 100.0 },
                ] {
                    let map = DisplayMap::new(colormap, range);
                    let mut view = ViewRenderer::new(640, 480, PixelFormat::Yuyv);
                    assert!(view.direct_yuyv(&out, &map), "pairs aligned");
                    assert!(
                        view.frame == via_rgb(&out, &map, 640, 480),
                        "{w}x{h} {colormap:?} {range:?}"
                    );
                    // And through `render`, RGB at the same size.
                    let rendered = view.render(&out, &map).expect("render").to_vec();
                    assert!(rendered == via_rgb(&out, &map, 640, 480));
                    let mut rgb = ViewRenderer::new(w, h, PixelFormat::Rgb24);
                    let mut want = vec![0u8; w * h * 3];
                    map.render_output_rgb8(&out, &mut want);
                    assert!(rgb.render(&out, &map).expect("render") == want.as_slice());
                }
            }
        }
    }

    /// The y4m planes of the RGB24 view, at the view size and letterboxed,
    /// for the signed image and for separated channels.
    #[test]
    fn yuv444_view_matches_the_rgb_path() {
        use crate::mode::SeparatedChannels;
        let (w, h) = (64, 48);
        let value = |i: usize| match i % 97 {
            0 => f32::NAN,
            1 => 1e6,
            k => (k as f32 - 48.0) * 7.5 + (i / w) as f32,
        };
        let img = |f: &dyn Fn(usize) -> f32| Image {
            width: w,
            height: h,
            data: (0..w * h).map(f).collect(),
        };
        let mut out = ModeOutput::new(w, h);
        out.signed_dn = img(&value);
        let mut with_channels = out.clone();
        with_channels.channels = Some(SeparatedChannels {
            i_plus_electrons: img(&|i| value(i) + 300.0),
            i_minus_electrons: img(&|i| value(i * 7)),
            i_plus_se_electrons: img(&|_| 1.0),
            i_minus_se_electrons: img(&|_| 1.0),
        });
        for out in [&out, &with_channels] {
            for colormap in [Colormap::Diverging, Colormap::Grey] {
                let map = DisplayMap::new(colormap, DisplayRange::SymmetricAuto);
                for (dw, dh) in [(w, h), (160, 90)] {
                    let mut rgb = ViewRenderer::new(dw, dh, PixelFormat::Rgb24);
                    let rgb = rgb.render(out, &map).expect("render").to_vec();
                    let n = dw * dh;
                    let mut want = vec![0u8; 3 * n];
                    let [y, u, v] = yuv444_planes_mut(&mut want);
                    rgb8_to_yuv444_planes(&rgb, y, u, v);
                    let mut view = ViewRenderer::new(dw, dh, PixelFormat::Rgb24);
                    let got = view.render_yuv444(out, &map);
                    assert!(got == want.as_slice(), "{dw}x{dh} {colormap:?}");
                }
            }
        }
    }

    /// Separated channels take the RGB path; its repeated rows are copied
    /// and must equal packing every row.
    #[test]
    fn channels_view_matches_packing_every_row() {
        use crate::mode::SeparatedChannels;
        for (w, h) in [(320, 240), (64, 48), (5, 3), (1, 1)] {
            let img = |f: &dyn Fn(usize) -> f32| Image {
                width: w,
                height: h,
                data: (0..w * h).map(f).collect(),
            };
            let mut out = ModeOutput::new(w, h);
            out.signed_dn = img(&|i| (i % 97) as f32 - 48.0);
            out.channels = Some(SeparatedChannels {
                i_plus_electrons: img(&|i| (i % 89) as f32 * 9.0),
                i_minus_electrons: img(&|i| {
                    if i % 13 == 0 {
                        f32::NAN
                    } else {
                        (i % 7) as f32
                    }
                }),
                i_plus_se_electrons: img(&|_| 1.0),
                i_minus_se_electrons: img(&|_| 1.0),
            });
            let map = DisplayMap::default();
            for (dw, dh) in [(640, 480), (16, 8)] {
                let mut view = ViewRenderer::new(dw, dh, PixelFormat::Yuyv);
                let got = view.render(&out, &map).expect("render").to_vec();
                assert!(got == via_rgb(&out, &map, dw, dh), "{w}x{h} into {dw}x{dh}");
            }
        }
    }

    #[test]
    fn odd_geometry_takes_the_rgb_path() {
        let (w, h) = (5, 3);
        let mut out = ModeOutput::new(w, h);
        out.signed_dn = Image {
            width: w,
            height: h,
            data: (0..w * h).map(|i| i as f32 - 7.0).collect(),
        };
        let map = DisplayMap::default();
        let mut view = ViewRenderer::new(16, 8, PixelFormat::Yuyv);
        assert!(!view.direct_yuyv(&out, &map));
        let got = view.render(&out, &map).expect("render").to_vec();
        assert_eq!(got, via_rgb(&out, &map, 16, 8));
    }
}
