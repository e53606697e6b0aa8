//! The v4l2loopback sink: a browser-safe view stream (YUYV 640x480, the
//! mode's rendering letterboxed and scaled) and optionally a raw data node
//! (Y16 at the sensor size, signed DN offset by 32768).

use sdi_core::image::Image;
use v4l2loopback_glue::{find_device, Input, LoopbackFormat, LoopbackWriter, PixelFormat};

use super::{Sink, SinkError, SinkInfo};
use sdi_core::display::{DisplayMap, DisplayRange};
use sdi_core::mode::ModeOutput;

pub struct LoopbackSink {
    view: LoopbackWriter,
    data: Option<LoopbackWriter>,
    rgb: Vec<u8>,
    scaled: Vec<u8>,
    /// The YUYV view rendered directly: the scaled signed image, its YUYV,
    /// and the whole frame with the bars.
    scaled_dn: Image<f32>,
    content: Vec<u8>,
    frame: Vec<u8>,
}

fn glue(e: v4l2loopback_glue::GlueError) -> SinkError {
    SinkError::Loopback(e)
}

impl LoopbackSink {
    /// Opens the view node labelled `label` and, if `data_label` is not empty, the data node.
    pub fn open(
        label: &str,
        data_label: &str,
        sensor_width: usize,
        sensor_height: usize,
        fps: f64,
    ) -> Result<Self, SinkError> {
        let fps = fps.round().clamp(1.0, 240.0) as u32;
        let dev = find_device(label).map_err(glue)?;
        let view = LoopbackWriter::open(&dev.path, LoopbackFormat::view(fps)).map_err(glue)?;
        let data = if data_label.is_empty() {
            None
        } else {
            let d = find_device(data_label).map_err(glue)?;
            Some(
                LoopbackWriter::open(
                    &d.path,
                    LoopbackFormat::raw(sensor_width as u32, sensor_height as u32, fps),
                )
                .map_err(glue)?,
            )
        };
        let c = view.config();
        Ok(Self {
            view,
            data,
            rgb: vec![0; sensor_width * sensor_height * 3],
            scaled: vec![0; c.width as usize * c.height as usize * 3],
            scaled_dn: Image::new(0, 0),
            content: Vec::new(),
            frame: Vec::new(),
        })
    }
}

/// Where [`letterbox`] puts a w x h image in dw x dh: (x0, y0, sw, sh).
fn letterbox_rect(w: usize, h: usize, dw: usize, dh: usize) -> (usize, usize, usize, usize) {
    let scale = (dw as f64 / w as f64).min(dh as f64 / h as f64);
    let (sw, sh) = ((w as f64 * scale) as usize, (h as f64 * scale) as usize);
    ((dw - sw) / 2, (dh - sh) / 2, sw, sh)
}

/// YUYV of black (RGB 0, 0, 0 through BT.601 limited range).
const BLACK_YUYV: [u8; 4] = [16, 128, 16, 128];

/// The YUYV view frame (dw x dh) of a signed image without separated
/// channels, rendered straight to YUYV: the image scaled as [`letterbox`]
/// scales the RGB, colormapped with the original image's range by
/// [`DisplayMap::render_yuyv`], black bars. The same bytes as the RGB path
/// (render, letterbox, v4l2loopback-glue's scalar RGB to YUYV) at a quarter
/// of its cost. `None` where pixel pairs would straddle a bar (odd bar or
/// content width): the RGB path handles those.
pub fn yuyv_view<'a>(
    output: &ModeOutput,
    display: &DisplayMap,
    (dw, dh): (usize, usize),
    scaled_dn: &mut Image<f32>,
    content: &mut Vec<u8>,
    frame: &'a mut Vec<u8>,
) -> Option<&'a [u8]> {
    let img = &output.signed_dn;
    let (w, h) = (img.width, img.height);
    if output.channels.is_some() || w == 0 || h == 0 || img.data.len() != w * h {
        return None;
    }
    let (x0, y0, sw, sh) = letterbox_rect(w, h, dw, dh);
    if x0 % 2 != 0 || sw % 2 != 0 || sw == 0 || sh == 0 {
        return None;
    }
    // One range from the image itself (the scaled copy repeats pixels).
    let map = DisplayMap::new(
        display.colormap,
        DisplayRange::Fixed {
            max_abs_dn: display.max_abs_dn(img),
        },
    );
    if scaled_dn.width != sw || scaled_dn.height != sh {
        *scaled_dn = Image::new(sw, sh);
    }
    let cols: Vec<usize> = (0..sw).map(|x| (x * w / sw).min(w - 1)).collect();
    for (y, row) in scaled_dn.data.chunks_exact_mut(sw).enumerate() {
        let src = &img.data[(y * h / sh).min(h - 1) * w..][..w];
        for (d, &sx) in row.iter_mut().zip(&cols) {
            *d = src[sx];
        }
    }
    content.resize(sw * sh * 2, 0);
    map.render_yuyv(scaled_dn, content);
    frame.resize(dw * dh * 2, 0);
    if (sw, sh) != (dw, dh) {
        for px in frame.chunks_exact_mut(4) {
            px.copy_from_slice(&BLACK_YUYV);
        }
    }
    for (y, row) in content.chunks_exact(sw * 2).enumerate() {
        frame[((y0 + y) * dw + x0) * 2..][..sw * 2].copy_from_slice(row);
    }
    Some(frame)
}

/// Nearest-neighbour scale of `src` (w x h RGB8) into `dst` (dw x dh),
/// preserving the aspect ratio with black bars.
pub fn letterbox(src: &[u8], w: usize, h: usize, dst: &mut [u8], dw: usize, dh: usize) {
    dst.fill(0);
    if w == 0 || h == 0 {
        return;
    }
    let (x0, y0, sw, sh) = letterbox_rect(w, h, dw, dh);
    for y in 0..sh {
        let sy = (y * h / sh).min(h - 1);
        let row = &mut dst[((y0 + y) * dw + x0) * 3..((y0 + y) * dw + x0 + sw) * 3];
        for (x, px) in row.chunks_exact_mut(3).enumerate() {
            let sx = (x * w / sw).min(w - 1);
            let s = (sy * w + sx) * 3;
            px.copy_from_slice(&src[s..s + 3]);
        }
    }
}

impl Sink for LoopbackSink {
    fn info(&self) -> SinkInfo {
        let c = self.view.config();
        let mut device = self.view.path().display().to_string();
        if let Some(d) = &self.data {
            device = format!("{device} + {} (Y16 data)", d.path().display());
        }
        SinkInfo {
            kind: "loopback",
            device,
            format: format!("{:?}", c.format).to_uppercase(),
            width: c.width,
            height: c.height,
        }
    }

    fn write(&mut self, output: &ModeOutput, display: &DisplayMap) -> Result<(), SinkError> {
        let img = &output.signed_dn;
        let c = self.view.config();
        let (dw, dh) = (c.width as usize, c.height as usize);
        let direct = match c.format {
            PixelFormat::Yuyv => yuyv_view(
                output,
                display,
                (dw, dh),
                &mut self.scaled_dn,
                &mut self.content,
                &mut self.frame,
            ),
            _ => None,
        };
        if let Some(yuyv) = direct {
            self.view
                .write(Input::Packed(yuyv), output.timestamp_us)
                .map_err(glue)?;
        } else {
            if self.rgb.len() != img.width * img.height * 3 {
                self.rgb.resize(img.width * img.height * 3, 0);
            }
            display.render_output_rgb8(output, &mut self.rgb);
            letterbox(&self.rgb, img.width, img.height, &mut self.scaled, dw, dh);
            self.view
                .write_rgb8(&self.scaled, output.timestamp_us)
                .map_err(glue)?;
        }
        if let Some(d) = &mut self.data {
            let dc = d.config();
            if dc.width as usize == img.width && dc.height as usize == img.height {
                d.write_signed_y16(&img.data, output.timestamp_us)
                    .map_err(glue)?;
            }
        }
        Ok(())
    }

    /// Readers of the view node plus the data node, from v4l2loopback's
    /// client-usage event; `None` when the module lacks it (0.12.x).
    fn watchers(&mut self) -> Option<u32> {
        let view = self.view.watchers()?;
        match &mut self.data {
            Some(d) => Some(view + d.watchers()?),
            None => Some(view),
        }
    }

    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
        self.view.write_no_signal(timestamp_us).map_err(glue)?;
        if let Some(d) = &mut self.data {
            d.write_no_signal(timestamp_us).map_err(glue)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{letterbox, yuyv_view};
    use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
    use sdi_core::image::Image;
    use sdi_core::mode::ModeOutput;
    use v4l2loopback_glue::{Converter, PixelFormat, Src, YuyvPath};

    /// The RGB path the direct YUYV view replaces: render, letterbox, glue scalar RGB to YUYV.
    fn via_rgb(out: &ModeOutput, map: &DisplayMap, dw: usize, dh: usize) -> Vec<u8> {
        let img = &out.signed_dn;
        let mut rgb = vec![0u8; img.width * img.height * 3];
        map.render_output_rgb8(out, &mut rgb);
        let mut scaled = vec![0u8; dw * dh * 3];
        letterbox(&rgb, img.width, img.height, &mut scaled, dw, dh);
        let mut yuyv = vec![0u8; dw * dh * 2];
        let mut conv = Converter::new(dw as u32, dh as u32, PixelFormat::Yuyv, YuyvPath::Scalar);
        conv.rgb8(Src::packed(&scaled, dw, dh, 3), &mut yuyv)
            .expect("convert");
        yuyv
    }

    #[test]
    fn direct_yuyv_view_matches_the_rgb_path() {
        // Full-width 2x (the boards' 320x240), side bars, top and bottom bars.
        for (w, h) in [(320, 240), (240, 240), (320, 120), (64, 48)] {
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
                    let (mut s, mut c, mut f) = (Image::new(0, 0), Vec::new(), Vec::new());
                    let direct = yuyv_view(&out, &map, (640, 480), &mut s, &mut c, &mut f)
                        .expect("pairs aligned")
                        .to_vec();
                    assert!(
                        direct == via_rgb(&out, &map, 640, 480),
                        "{w}x{h} {colormap:?} {range:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn letterbox_doubles_qvga() {
        let src: Vec<u8> = (0..4 * 3 * 3).map(|i| i as u8).collect();
        let mut dst = vec![0u8; 8 * 6 * 3];
        letterbox(&src, 4, 3, &mut dst, 8, 6);
        assert_eq!(&dst[0..3], &src[0..3]);
        assert_eq!(&dst[3..6], &src[0..3]);
        assert_eq!(&dst[(8 * 5 + 7) * 3..], &src[(4 * 2 + 3) * 3..]);
    }
}
