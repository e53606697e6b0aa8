//! The v4l2loopback sink: a browser-safe view stream (YUYV 640x480, the
//! mode's rendering letterboxed and scaled) and optionally a raw data node
//! (Y16 at the sensor size, signed DN offset by 32768).

use v4l2loopback_glue::{find_device, LoopbackFormat, LoopbackWriter};

use super::{Sink, SinkError, SinkInfo};
use crate::modes::{DisplayMap, ModeOutput};

pub struct LoopbackSink {
    view: LoopbackWriter,
    data: Option<LoopbackWriter>,
    rgb: Vec<u8>,
    scaled: Vec<u8>,
}

fn glue(e: v4l2loopback_glue::GlueError) -> SinkError {
    SinkError::Unavailable(e.to_string())
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
        })
    }
}

/// Nearest-neighbour scale of `src` (w x h RGB8) into `dst` (dw x dh),
/// preserving the aspect ratio with black bars.
pub fn letterbox(src: &[u8], w: usize, h: usize, dst: &mut [u8], dw: usize, dh: usize) {
    dst.fill(0);
    if w == 0 || h == 0 {
        return;
    }
    let scale = (dw as f64 / w as f64).min(dh as f64 / h as f64);
    let (sw, sh) = ((w as f64 * scale) as usize, (h as f64 * scale) as usize);
    let (x0, y0) = ((dw - sw) / 2, (dh - sh) / 2);
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
        if self.rgb.len() != img.width * img.height * 3 {
            self.rgb.resize(img.width * img.height * 3, 0);
        }
        display.render_output_rgb8(output, &mut self.rgb);
        let c = self.view.config();
        letterbox(
            &self.rgb,
            img.width,
            img.height,
            &mut self.scaled,
            c.width as usize,
            c.height as usize,
        );
        self.view
            .write_rgb8(&self.scaled, output.timestamp_us)
            .map_err(glue)?;
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

    fn write_no_signal(&mut self) -> Result<(), SinkError> {
        self.view.write_no_signal().map_err(glue)?;
        if let Some(d) = &mut self.data {
            d.write_no_signal().map_err(glue)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::letterbox;

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
