//! The v4l2loopback sink: a browser-safe view stream (YUYV 640x480, the
//! mode's rendering letterboxed and scaled) and optionally a raw data node
//! (Y16 at the sensor size, signed DN offset by 32768).

use sdi_core::view::ViewRenderer;
use v4l2loopback_glue::{
    find_or_add_device, CreateOptions, LoopbackDevice, LoopbackFormat, LoopbackWriter, PixelFormat,
};

use super::{Sink, SinkError, SinkInfo, SinkKindName};
use crate::out_frame::OutFrame;

pub struct LoopbackSink {
    view: LoopbackWriter,
    data: Option<LoopbackWriter>,
    /// Renders the view node's frames, and the data node's.
    view_frames: ViewRenderer,
    data_frames: ViewRenderer,
}

impl LoopbackSink {
    /// Opens the view node labelled `label` and, if `data_label` is not
    /// empty, the data node; each added first if missing ([`node`]).
    pub fn open(
        label: &str,
        data_label: &str,
        sensor_width: usize,
        sensor_height: usize,
        fps: f64,
    ) -> Result<Self, SinkError> {
        let fps = fps.round().clamp(1.0, 240.0) as u32;
        let dev = node(label)?;
        let view = LoopbackWriter::open(&dev.path, LoopbackFormat::view(fps))?;
        let data = if data_label.is_empty() {
            None
        } else {
            let d = node(data_label)?;
            Some(LoopbackWriter::open(
                &d.path,
                LoopbackFormat::raw(sensor_width as u32, sensor_height as u32, fps),
            )?)
        };
        let c = view.config();
        Ok(Self {
            view,
            data,
            view_frames: ViewRenderer::new(c.width as usize, c.height as usize, c.format),
            data_frames: ViewRenderer::new(sensor_width, sensor_height, PixelFormat::Y16),
        })
    }
}

/// The loopback node labelled `label`, added through `/dev/v4l2loopback`
/// when there is none and the module and our rights allow (v4l2loopback
/// 0.13+, root), like the shipped modprobe config's node: exclusive caps,
/// a ring of 10. Labels come from the camera plan only (serials checked by
/// `names_a_file`), never from a D-Bus client. Added nodes stay when sdid
/// stops: the next sdid finds them by label, as it finds modprobe's, and a
/// reader holding one open keeps it across a restart.
fn node(label: &str) -> Result<LoopbackDevice, SinkError> {
    let found = find_or_add_device(&CreateOptions::new(label))?;
    if found.added {
        tracing::info!(
            "added v4l2loopback node {} labelled \"{label}\"",
            found.device.path.display()
        );
    }
    Ok(found.device)
}

impl Sink for LoopbackSink {
    fn info(&self) -> SinkInfo {
        let c = self.view.config();
        let mut device = self.view.path().display().to_string();
        if let Some(d) = &self.data {
            device = format!("{device} + {} (Y16 data)", d.path().display());
        }
        SinkInfo {
            kind: SinkKindName::Loopback,
            device,
            format: format!("{:?}", c.format).to_uppercase(),
            width: c.width,
            height: c.height,
        }
    }

    fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError> {
        let stamp_us = frame.output.timestamp_us;
        let view = frame.view(&mut self.view_frames)?;
        self.view.write(&view, stamp_us)?;
        if let Some(d) = &mut self.data {
            let (dc, img) = (d.config(), &frame.output.signed_dn);
            if dc.width as usize == img.width && dc.height as usize == img.height {
                let data = frame.signed_dn(&mut self.data_frames)?;
                d.write(&data, stamp_us)?;
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
        self.view.write_no_signal(timestamp_us)?;
        if let Some(d) = &mut self.data {
            d.write_no_signal(timestamp_us)?;
        }
        Ok(())
    }
}
