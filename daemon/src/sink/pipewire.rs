//! The PipeWire sink: a camera without a kernel module. The nodes belong to
//! the per-user camera process (`sdi-pipewire-camera`, [`launch`]), which outlives
//! sdid so readers survive a restart; this sink renders what the camera's
//! readers negotiated (YUYV or RGB at the view size, Y16 at the sensor size)
//! and sends it there. When the camera process goes away it is started
//! again, at most every [`RETRY`].

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use sdi_core::mode::ModeId;
use v4l2loopback_glue::{Converter, LoopbackFormat, PixelFormat, Src, YuyvPath};

use super::pipewire_launch as launch;
use super::{Sink, SinkError, SinkInfo};
use sdi_camera_link::{self as link, Message, Port, Spec, State, Wire};
pub use sdi_camera_link::{
    view_description, CAMERA_PROGRAM, DATA_NODE, FRAME_LOG, LINGER, VIEW_NODE,
};
use sdi_core::display::DisplayMap;
use sdi_core::mode::ModeOutput;

/// Between attempts to reach a camera process that went away.
const RETRY: Duration = Duration::from_secs(2);

fn rendering(e: v4l2loopback_glue::GlueError) -> SinkError {
    SinkError::Unavailable(format!("rendering for PipeWire: {e}"))
}

/// The link to the camera process, and what it last reported.
struct Link {
    writer: UnixStream,
    report: Arc<Report>,
    camera_pid: Option<u32>,
}

#[derive(Default)]
struct Report {
    state: Mutex<State>,
    closed: AtomicBool,
}

impl Link {
    fn open(program: &Path, spec: &Spec) -> Result<Self, SinkError> {
        let c = launch::connect(program, spec).map_err(SinkError::Unavailable)?;
        let report = Arc::new(Report::default());
        let mut reader = c.stream.try_clone()?;
        let r = report.clone();
        std::thread::Builder::new()
            .name("sdid-camera-link".into())
            .spawn(move || {
                while let Ok(m) = link::read(&mut reader) {
                    if let Message::State(s) = m {
                        *r.state.lock().unwrap_or_else(|e| e.into_inner()) = s;
                    }
                }
                r.closed.store(true, Ordering::Release);
            })?;
        Ok(Self {
            writer: c.stream,
            report,
            camera_pid: c.camera_pid,
        })
    }

    fn state(&self) -> State {
        *self.report.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn alive(&self) -> bool {
        !self.report.closed.load(Ordering::Acquire)
    }
}

/// Feeds the PipeWire camera.
pub struct PipewireSink {
    program: PathBuf,
    spec: Spec,
    link: Option<Link>,
    retry_at: Instant,
    view: LoopbackFormat,
    yuyv: Converter,
    rgb24: Converter,
    y16: Converter,
    /// The mode's rendering at the sensor size, letterboxed to the view,
    /// and the bytes sent.
    rgb: Vec<u8>,
    scaled: Vec<u8>,
    bytes: Vec<u8>,
}

impl PipewireSink {
    /// Connects to this user's camera process (`program`, found by
    /// [`launch::find_program`]), starting it when none runs; fails when it
    /// cannot reach PipeWire.
    pub fn open(
        program: &Path,
        sensor_width: usize,
        sensor_height: usize,
        frame_rate_hz: f64,
        mode: ModeId,
    ) -> Result<Self, SinkError> {
        let frame_rate_hz = frame_rate_hz.round().clamp(1.0, 240.0) as u32;
        let view = LoopbackFormat::view(frame_rate_hz);
        let spec = Spec {
            view_width: view.width,
            view_height: view.height,
            data_width: sensor_width as u32,
            data_height: sensor_height as u32,
            frame_rate_hz,
            mode,
        };
        let link = Link::open(program, &spec)?;
        Ok(Self {
            program: program.to_path_buf(),
            link: Some(link),
            retry_at: Instant::now(),
            yuyv: Converter::new(
                view.width,
                view.height,
                PixelFormat::Yuyv,
                YuyvPath::fastest(),
            ),
            rgb24: Converter::new(
                view.width,
                view.height,
                PixelFormat::Rgb24,
                YuyvPath::Scalar,
            ),
            y16: Converter::new(
                spec.data_width,
                spec.data_height,
                PixelFormat::Y16,
                YuyvPath::Scalar,
            ),
            rgb: vec![0; sensor_width * sensor_height * 3],
            scaled: vec![0; view.width as usize * view.height as usize * 3],
            bytes: Vec::new(),
            view,
            spec,
        })
    }

    /// What the camera process last reported.
    fn state(&self) -> State {
        self.link.as_ref().map(Link::state).unwrap_or_default()
    }

    /// Buffers the camera published so far: (view, data), as last reported.
    pub fn published(&self) -> (u64, u64) {
        let s = self.state();
        (s.view_published, s.data_published)
    }

    /// True while a reader streams the view node.
    pub fn view_streaming(&self) -> bool {
        self.state().view.is_some()
    }

    /// The camera process, when known.
    pub fn camera_pid(&self) -> Option<u32> {
        self.link.as_ref().and_then(|l| l.camera_pid)
    }

    /// Asks the camera process to end now (not just linger).
    pub fn stop_camera(&mut self) {
        if let Some(mut l) = self.link.take() {
            let _ = link::write(&mut l.writer, &Message::Quit);
        }
    }

    /// The live link, reconnecting (at most every [`RETRY`]) after the
    /// camera process went away.
    fn link(&mut self) -> Result<&mut Link, SinkError> {
        if self.link.as_ref().is_some_and(|l| !l.alive()) {
            self.link = None;
            tracing::warn!("the PipeWire camera process went away; starting it again");
        }
        if self.link.is_none() {
            if Instant::now() < self.retry_at {
                return Err(SinkError::Unavailable(
                    "the PipeWire camera process is gone".into(),
                ));
            }
            self.retry_at = Instant::now() + RETRY;
            self.link = Some(Link::open(&self.program, &self.spec)?);
        }
        self.link
            .as_mut()
            .ok_or_else(|| SinkError::Unavailable("no PipeWire camera".into()))
    }

    fn send(&mut self, port: Port, wire: Wire, timestamp_us: u64) -> Result<(), SinkError> {
        let bytes = std::mem::take(&mut self.bytes);
        let r = self.link().and_then(|l| {
            link::write_frame(&mut l.writer, port, wire, timestamp_us, &bytes).map_err(Into::into)
        });
        self.bytes = bytes;
        self.closed_on_error(r)
    }

    /// Drops the link after a failed write (the next frame reconnects).
    fn closed_on_error(&mut self, r: Result<(), SinkError>) -> Result<(), SinkError> {
        if r.is_err() {
            if let Some(l) = self.link.take() {
                let _ = l.writer.shutdown(std::net::Shutdown::Both);
            }
        }
        r
    }

    fn message(&mut self, m: &Message) -> Result<(), SinkError> {
        let r = self.link().and_then(|l| {
            link::write(&mut l.writer, m)?;
            l.writer.flush().map_err(Into::into)
        });
        self.closed_on_error(r)
    }
}

impl Sink for PipewireSink {
    fn info(&self) -> SinkInfo {
        SinkInfo {
            kind: "pipewire",
            device: format!(
                "PipeWire node \"{VIEW_NODE}\" (YUYV or RGB) + \"{DATA_NODE}\" ({}x{} Y16)",
                self.spec.data_width, self.spec.data_height
            ),
            format: "YUYV".into(),
            width: self.view.width,
            height: self.view.height,
        }
    }

    fn write(&mut self, output: &ModeOutput, display: &DisplayMap) -> Result<(), SinkError> {
        let state = self.link()?.state();
        let img = &output.signed_dn;
        let stamp_us = output.timestamp_us;
        let (vw, vh) = (self.view.width as usize, self.view.height as usize);
        if let Some(wire) = state.view {
            if self.rgb.len() != img.width * img.height * 3 {
                self.rgb.resize(img.width * img.height * 3, 0);
            }
            display.render_output_rgb8(output, &mut self.rgb);
            super::loopback::letterbox(&self.rgb, img.width, img.height, &mut self.scaled, vw, vh);
            self.bytes.resize(vw * vh * wire.bytes_per_pixel(), 0);
            let conv = if wire == Wire::Rgb {
                &mut self.rgb24
            } else {
                &mut self.yuyv
            };
            conv.rgb8(Src::packed(&self.scaled, vw, vh, 3), &mut self.bytes)
                .map_err(rendering)?;
            self.send(Port::View, wire, stamp_us)?;
        }
        let (dw, dh) = (
            self.spec.data_width as usize,
            self.spec.data_height as usize,
        );
        if state.data == Some(Wire::Y16) && img.width == dw && img.height == dh {
            self.bytes.resize(dw * dh * 2, 0);
            self.y16
                .signed_dn(Src::packed(&img.data, dw, dh, 1), &mut self.bytes)
                .map_err(rendering)?;
            self.send(Port::Data, Wire::Y16, stamp_us)?;
        }
        Ok(())
    }

    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
        self.message(&Message::NoSignal { timestamp_us })
    }

    /// Streams a reader has started (view plus data).
    fn watchers(&mut self) -> Option<u32> {
        let s = self.state();
        Some(u32::from(s.view.is_some()) + u32::from(s.data.is_some()))
    }

    fn set_mode(&mut self, mode: ModeId) {
        if self.spec.mode != mode {
            self.spec.mode = mode;
            let _ = self.message(&Message::Mode(mode));
        }
    }
}
