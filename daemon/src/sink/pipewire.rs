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
use sdi_core::view::{PixelFormat, ViewRenderer};
use v4l2loopback_glue::LoopbackFormat;

use super::pipewire_launch as launch;
use super::{Sink, SinkError, SinkInfo, SinkKindName};
use crate::out_frame::OutFrame;
use sdi_camera_link::{self as link, Message, Port, Spec, State, Wire};
pub use sdi_camera_link::{
    Names, CAMERA_PROGRAM, DATA_NODE, FRAME_LOG, LINGER, SYSTEM_FEED_FLAG, SYSTEM_FEED_NAME,
    VIEW_NODE,
};

/// Between attempts to reach a camera process that went away.
const RETRY: Duration = Duration::from_secs(2);

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
        Self::over(launch::connect(program, spec)?)
    }

    /// The link over a greeted connection.
    fn over(c: launch::Connected) -> Result<Self, SinkError> {
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

/// The camera process as sdid reaches it: the live link, reconnected
/// after the process went away.
struct Camera {
    /// Started again when it went away; `None`: a camera that connected
    /// to sdid (the system feed), gone for good with its link.
    program: Option<PathBuf>,
    spec: Spec,
    link: Option<Link>,
    retry_at: Instant,
    /// Start the camera process only once this user's PipeWire runs.
    awaits_pipewire: bool,
}

impl Camera {
    /// What the camera process last reported.
    fn state(&self) -> State {
        self.link.as_ref().map(Link::state).unwrap_or_default()
    }

    /// The live link, reconnecting (at most every [`RETRY`]) after the
    /// camera process went away.
    fn link(&mut self) -> Result<&mut Link, SinkError> {
        if self.link.as_ref().is_some_and(|l| !l.alive()) {
            self.link = None;
            if self.program.is_some() {
                tracing::warn!("the PipeWire camera process went away; starting it again");
            }
        }
        if self.link.is_none() {
            if Instant::now() < self.retry_at {
                return Err(SinkError::CameraGone);
            }
            let Some(program) = &self.program else {
                return Err(SinkError::CameraGone);
            };
            self.retry_at = Instant::now() + RETRY;
            if self.awaits_pipewire && launch::pipewire_socket().is_none() {
                return Err(SinkError::NoPipewire);
            }
            self.link = Some(Link::open(program, &self.spec)?);
        }
        self.link.as_mut().ok_or(SinkError::CameraGone)
    }

    fn send(
        &mut self,
        port: Port,
        wire: Wire,
        timestamp_us: u64,
        bytes: &[u8],
    ) -> Result<(), SinkError> {
        let r = self.link().and_then(|l| {
            link::write_frame(&mut l.writer, port, wire, timestamp_us, bytes).map_err(Into::into)
        });
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

/// Feeds the PipeWire camera.
pub struct PipewireSink {
    camera: Camera,
    view: LoopbackFormat,
    /// Renders the view node's frames in the wire its readers negotiated,
    /// and the data node's.
    yuyv: ViewRenderer,
    rgb24: ViewRenderer,
    y16: ViewRenderer,
}

impl PipewireSink {
    /// Connects to this user's process of the camera `spec`
    /// (`program`, found by [`launch::find_program`]), starting it when
    /// none runs; fails when it cannot reach PipeWire.
    pub fn open(program: &Path, spec: Spec) -> Result<Self, SinkError> {
        let mut s = Self::when_reachable(program, spec);
        s.camera.awaits_pipewire = false;
        s.camera.link = Some(Link::open(program, &s.camera.spec)?);
        Ok(s)
    }

    /// The spec sdid greets a camera with for these sizes, rate and mode;
    /// `camera`: the serial of one of several cameras, which names its
    /// process's socket and nodes (`None`: the lone camera).
    pub fn spec(
        sensor_width: usize,
        sensor_height: usize,
        frame_rate_hz: f64,
        mode: ModeId,
        camera: Option<&str>,
    ) -> Spec {
        let frame_rate_hz = frame_rate_hz.round().clamp(1.0, 240.0) as u32;
        let view = LoopbackFormat::view(frame_rate_hz);
        Spec {
            view_width: view.width,
            view_height: view.height,
            data_width: sensor_width as u32,
            data_height: sensor_height as u32,
            frame_rate_hz,
            mode,
            camera: camera.map(str::to_owned),
        }
    }

    /// Feeds a camera process that connected to sdid and was greeted with
    /// `spec` (the system feed); it is not started again when it goes.
    pub fn over(c: launch::Connected, spec: Spec) -> Result<Self, SinkError> {
        let view = LoopbackFormat::view(spec.frame_rate_hz);
        let (vw, vh) = (view.width as usize, view.height as usize);
        let (dw, dh) = (spec.data_width as usize, spec.data_height as usize);
        Ok(Self {
            camera: Camera {
                program: None,
                spec,
                link: Some(Link::over(c)?),
                retry_at: Instant::now(),
                awaits_pipewire: false,
            },
            yuyv: ViewRenderer::new(vw, vh, PixelFormat::Yuyv),
            rgb24: ViewRenderer::new(vw, vh, PixelFormat::Rgb24),
            y16: ViewRenderer::new(dw, dh, PixelFormat::Y16),
            view,
        })
    }

    /// Like [`PipewireSink::open`], but reaches (or starts) the camera
    /// process with the first frame after this user's PipeWire is up, and
    /// again after it went away, at most every [`RETRY`].
    pub fn when_reachable(program: &Path, spec: Spec) -> Self {
        let view = LoopbackFormat::view(spec.frame_rate_hz);
        let (vw, vh) = (view.width as usize, view.height as usize);
        let (dw, dh) = (spec.data_width as usize, spec.data_height as usize);
        Self {
            camera: Camera {
                program: Some(program.to_path_buf()),
                spec,
                link: None,
                retry_at: Instant::now(),
                awaits_pipewire: true,
            },
            yuyv: ViewRenderer::new(vw, vh, PixelFormat::Yuyv),
            rgb24: ViewRenderer::new(vw, vh, PixelFormat::Rgb24),
            y16: ViewRenderer::new(dw, dh, PixelFormat::Y16),
            view,
        }
    }

    /// Buffers the camera published so far: (view, data), as last reported.
    pub fn published(&self) -> (u64, u64) {
        let s = self.camera.state();
        (s.view_published, s.data_published)
    }

    /// True while a reader streams the view node.
    pub fn view_streaming(&self) -> bool {
        self.camera.state().view.is_some()
    }

    /// The camera process, when known.
    pub fn camera_pid(&self) -> Option<u32> {
        self.camera.link.as_ref().and_then(|l| l.camera_pid)
    }

    /// Asks the camera process to end now (not just linger).
    pub fn stop_camera(&mut self) {
        if let Some(mut l) = self.camera.link.take() {
            let _ = link::write(&mut l.writer, &Message::Quit);
        }
    }
}

impl Sink for PipewireSink {
    fn info(&self) -> SinkInfo {
        SinkInfo {
            kind: SinkKindName::Pipewire,
            device: format!(
                "PipeWire node \"{}\" (YUYV or RGB) + \"{}\" ({}x{} Y16)",
                self.camera.spec.names().view_node(),
                self.camera.spec.names().data_node(),
                self.camera.spec.data_width,
                self.camera.spec.data_height
            ),
            format: "YUYV".into(),
            width: self.view.width,
            height: self.view.height,
        }
    }

    fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError> {
        if self.camera.spec.mode != frame.mode {
            // The camera names its view node after the mode; a camera
            // reached later is greeted with it.
            self.camera.spec.mode = frame.mode;
            let _ = self.camera.message(&Message::Mode(frame.mode));
        }
        let state = self.camera.link()?.state();
        let img = &frame.output.signed_dn;
        let stamp_us = frame.output.timestamp_us;
        if let Some(wire) = state.view {
            let view = match wire {
                Wire::Rgb => &mut self.rgb24,
                _ => &mut self.yuyv,
            };
            let bytes = frame.view(view)?;
            self.camera.send(Port::View, wire, stamp_us, &bytes)?;
        }
        let spec = &self.camera.spec;
        let (dw, dh) = (spec.data_width as usize, spec.data_height as usize);
        if state.data == Some(Wire::Y16) && img.width == dw && img.height == dh {
            let bytes = frame.signed_dn(&mut self.y16)?;
            self.camera.send(Port::Data, Wire::Y16, stamp_us, &bytes)?;
        }
        Ok(())
    }

    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
        self.camera.message(&Message::NoSignal { timestamp_us })
    }

    /// Streams a reader has started (view plus data).
    fn watchers(&mut self) -> Option<u32> {
        let s = self.camera.state();
        Some(u32::from(s.view.is_some()) + u32::from(s.data.is_some()))
    }
}
