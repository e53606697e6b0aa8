//! The PipeWire sink: a camera without a kernel module. Two output streams:
//! the view (`Video/Source`, `media.role = Camera`, YUYV or RGB at the
//! v4l2loopback view size) and the raw data (`Video/Source`, Y16 at the
//! sensor size, signed DN offset by 32768, no camera role so camera pickers
//! skip it).
//!
//! PipeWire's loop runs on its own thread ("sdid-pipewire"). The output
//! thread renders only what a connected reader negotiated, into a one-frame
//! slot per stream, and wakes the loop; the loop copies the slot into a
//! PipeWire buffer (dropping the frame when the reader holds every buffer).
//! Frames therefore never wait on PipeWire or its readers.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use pipewire as pw;
use pw::spa;
use sdi_core::mode::ModeId;
use spa::pod::{ChoiceValue, Object, Pod, Property, Value};
use spa::utils::{Choice, ChoiceEnum, ChoiceFlags, Fraction, Id, Rectangle};
use v4l2loopback_glue::{no_signal_grey, Converter, LoopbackFormat, PixelFormat, Src, YuyvPath};

use super::{Sink, SinkError, SinkInfo};
use crate::modes::{DisplayMap, ModeOutput};

/// Node name of the view stream (what `pipewiresrc target-object=` takes).
pub const VIEW_NODE: &str = "sdi-camera";
/// Node name of the raw Y16 data stream.
pub const DATA_NODE: &str = "sdi-camera-data";
/// `tracing` target of the per-frame log (CRC-32 of each published buffer),
/// enabled with `RUST_LOG=sdid::pipewire::frames=trace`.
pub const FRAME_LOG: &str = "sdid::pipewire::frames";
/// How long [`PipewireSink::open`] waits for the PipeWire thread to connect.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// Buffers per stream: the reader may hold some while we fill another.
const BUFFERS: (i32, i32, i32) = (4, 2, 8);

/// Pixel formats on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Wire {
    Yuyv = 1,
    Rgb = 2,
    Y16 = 3,
}

impl Wire {
    fn spa(self) -> spa::param::video::VideoFormat {
        use spa::param::video::VideoFormat;
        match self {
            Wire::Yuyv => VideoFormat::YUY2,
            Wire::Rgb => VideoFormat::RGB,
            Wire::Y16 => VideoFormat::GRAY16_LE,
        }
    }

    fn from_spa(f: spa::param::video::VideoFormat) -> Option<Self> {
        [Wire::Yuyv, Wire::Rgb, Wire::Y16]
            .into_iter()
            .find(|w| w.spa() == f)
    }

    fn from_code(c: u8) -> Option<Self> {
        [Wire::Yuyv, Wire::Rgb, Wire::Y16]
            .into_iter()
            .find(|w| *w as u8 == c)
    }

    fn glue(self) -> PixelFormat {
        match self {
            Wire::Yuyv => PixelFormat::Yuyv,
            Wire::Rgb => PixelFormat::Rgb24,
            Wire::Y16 => PixelFormat::Y16,
        }
    }

    fn bytes_per_pixel(self) -> usize {
        self.glue().bytes_per_pixel()
    }

    fn name(self) -> &'static str {
        match self {
            Wire::Yuyv => "YUYV",
            Wire::Rgb => "RGB",
            Wire::Y16 => "Y16",
        }
    }
}

/// A rendered frame waiting for the PipeWire thread.
struct Pending {
    bytes: Vec<u8>,
    wire: Wire,
    mode: &'static str,
    /// Capture time (CLOCK_MONOTONIC, the frame loop's publish clock); 0:
    /// unknown, stamped when published.
    timestamp_us: u64,
}

#[derive(Default)]
struct Slot {
    pending: Option<Pending>,
    /// The last consumed frame's allocation, reused.
    spare: Vec<u8>,
}

/// One stream as both threads see it.
struct Port {
    /// `Wire` code negotiated while a reader streams; 0 when nobody does.
    streaming: AtomicU8,
    slot: Mutex<Slot>,
    /// Buffers handed to PipeWire.
    published: AtomicU64,
}

impl Port {
    fn new() -> Self {
        Self {
            streaming: AtomicU8::new(0),
            slot: Mutex::new(Slot::default()),
            published: AtomicU64::new(0),
        }
    }

    fn wire(&self) -> Option<Wire> {
        Wire::from_code(self.streaming.load(Ordering::Acquire))
    }

    fn slot(&self) -> MutexGuard<'_, Slot> {
        // A panic while holding the slot leaves plain bytes behind: keep going.
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }
}

struct Shared {
    view: Port,
    data: Port,
    /// A wake-up is queued on the loop's channel (keeps the channel at one message).
    woken: AtomicBool,
    /// Set by the loop when the PipeWire connection is lost.
    broken: AtomicBool,
}

enum Msg {
    /// New frames in the slots.
    Wake,
    /// The mode changed: new node descriptions.
    Mode(&'static str),
    Quit,
}

/// What the loop thread sets up.
struct Spec {
    view_width: u32,
    view_height: u32,
    data_width: u32,
    data_height: u32,
    frame_rate_hz: u32,
    mode: &'static str,
}

/// Publishes the camera as PipeWire nodes.
pub struct PipewireSink {
    shared: Arc<Shared>,
    tx: pw::channel::Sender<Msg>,
    thread: Option<JoinHandle<()>>,
    view: LoopbackFormat,
    data_width: usize,
    data_height: usize,
    mode: Option<ModeId>,
    yuyv: Converter,
    rgb24: Converter,
    y16: Converter,
    /// The mode's rendering at the sensor size, then letterboxed to the view.
    rgb: Vec<u8>,
    scaled: Vec<u8>,
    /// The "no signal" card (grey, view size) and its Y16 rendering at the sensor size.
    no_signal_view: Vec<u8>,
    no_signal_data: Vec<u8>,
}

/// The node description readers show, e.g. "SDI camera (depth-edge)".
pub fn view_description(mode: &str) -> String {
    format!("SDI camera ({mode})")
}

fn data_description(mode: &str) -> String {
    format!("SDI camera raw data, Y16 DN+32768 ({mode})")
}

impl PipewireSink {
    /// Connects to the PipeWire daemon of this user (`$PIPEWIRE_REMOTE`, else
    /// `$XDG_RUNTIME_DIR/pipewire-0`) and creates both nodes; fails when no
    /// daemon answers.
    pub fn open(
        sensor_width: usize,
        sensor_height: usize,
        frame_rate_hz: f64,
        mode: ModeId,
    ) -> Result<Self, SinkError> {
        let frame_rate_hz = frame_rate_hz.round().clamp(1.0, 240.0) as u32;
        let view = LoopbackFormat::view(frame_rate_hz);
        let shared = Arc::new(Shared {
            view: Port::new(),
            data: Port::new(),
            woken: AtomicBool::new(false),
            broken: AtomicBool::new(false),
        });
        let spec = Spec {
            view_width: view.width,
            view_height: view.height,
            data_width: sensor_width as u32,
            data_height: sensor_height as u32,
            frame_rate_hz,
            mode: mode.name(),
        };
        let (tx, rx) = pw::channel::channel::<Msg>();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), String>>();
        let loop_shared = shared.clone();
        let thread = std::thread::Builder::new()
            .name("sdid-pipewire".into())
            .spawn(move || run_loop(spec, loop_shared, rx, ready_tx))?;
        match ready_rx.recv_timeout(CONNECT_TIMEOUT) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let _ = thread.join();
                return Err(SinkError::Unavailable(e));
            }
            Err(_) => {
                let _ = tx.send(Msg::Quit);
                return Err(SinkError::Unavailable(format!(
                    "PipeWire did not answer within {} s",
                    CONNECT_TIMEOUT.as_secs()
                )));
            }
        }
        let (vw, vh) = (view.width as usize, view.height as usize);
        let no_signal_view = no_signal_grey(vw, vh);
        let mut y16 = Converter::new(
            sensor_width as u32,
            sensor_height as u32,
            PixelFormat::Y16,
            YuyvPath::Scalar,
        );
        let data_grey = no_signal_grey(sensor_width, sensor_height);
        let mut no_signal_data = vec![0; sensor_width * sensor_height * 2];
        let _ = y16.grey8(
            Src::packed(&data_grey, sensor_width, sensor_height, 1),
            &mut no_signal_data,
        );
        Ok(Self {
            shared,
            tx,
            thread: Some(thread),
            view,
            data_width: sensor_width,
            data_height: sensor_height,
            mode: Some(mode),
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
            y16,
            rgb: vec![0; sensor_width * sensor_height * 3],
            scaled: vec![0; vw * vh * 3],
            no_signal_view,
            no_signal_data,
        })
    }

    /// Buffers handed to PipeWire so far: (view, data).
    pub fn published(&self) -> (u64, u64) {
        (
            self.shared.view.published.load(Ordering::Relaxed),
            self.shared.data.published.load(Ordering::Relaxed),
        )
    }

    /// True while a reader streams the view node.
    pub fn view_streaming(&self) -> bool {
        self.shared.view.wire().is_some()
    }

    fn mode_name(&self) -> &'static str {
        self.mode.map_or("", ModeId::name)
    }

    /// Puts `fill`'s bytes into `port`'s slot (when a reader streams it),
    /// replacing a frame the loop has not taken yet; true if queued.
    fn offer(
        port: &Port,
        mode: &'static str,
        timestamp_us: u64,
        fill: impl FnOnce(Wire, &mut Vec<u8>) -> bool,
    ) -> bool {
        let Some(wire) = port.wire() else {
            return false;
        };
        let mut bytes = std::mem::take(&mut port.slot().spare);
        if !fill(wire, &mut bytes) {
            port.slot().spare = bytes;
            return false;
        }
        let mut slot = port.slot();
        if let Some(old) = slot.pending.replace(Pending {
            bytes,
            wire,
            mode,
            timestamp_us,
        }) {
            slot.spare = old.bytes;
        }
        true
    }

    fn wake(&self) -> Result<(), SinkError> {
        if self.shared.broken.load(Ordering::Relaxed) {
            return Err(SinkError::Unavailable(
                "the PipeWire connection was lost".into(),
            ));
        }
        if !self.shared.woken.swap(true, Ordering::AcqRel) && self.tx.send(Msg::Wake).is_err() {
            return Err(SinkError::Unavailable(
                "the PipeWire thread has stopped".into(),
            ));
        }
        Ok(())
    }
}

impl Sink for PipewireSink {
    fn info(&self) -> SinkInfo {
        SinkInfo {
            kind: "pipewire",
            device: format!(
                "PipeWire node \"{VIEW_NODE}\" (YUYV or RGB) + \"{DATA_NODE}\" ({}x{} Y16)",
                self.data_width, self.data_height
            ),
            format: "YUYV".into(),
            width: self.view.width,
            height: self.view.height,
        }
    }

    fn write(&mut self, output: &ModeOutput, display: &DisplayMap) -> Result<(), SinkError> {
        let img = &output.signed_dn;
        let (mode, stamp_us) = (self.mode_name(), output.timestamp_us);
        let (vw, vh) = (self.view.width as usize, self.view.height as usize);
        let mut queued = false;
        if self.shared.view.wire().is_some() {
            if self.rgb.len() != img.width * img.height * 3 {
                self.rgb.resize(img.width * img.height * 3, 0);
            }
            display.render_output_rgb8(output, &mut self.rgb);
            super::loopback::letterbox(&self.rgb, img.width, img.height, &mut self.scaled, vw, vh);
            let (scaled, yuyv, rgb24) = (&self.scaled, &mut self.yuyv, &mut self.rgb24);
            queued |= Self::offer(&self.shared.view, mode, stamp_us, |wire, bytes| {
                bytes.resize(vw * vh * wire.bytes_per_pixel(), 0);
                let conv = if wire == Wire::Rgb { rgb24 } else { yuyv };
                conv.rgb8(Src::packed(scaled, vw, vh, 3), bytes).is_ok()
            });
        }
        if img.width == self.data_width && img.height == self.data_height {
            let (w, h, y16) = (self.data_width, self.data_height, &mut self.y16);
            queued |= Self::offer(&self.shared.data, mode, stamp_us, |_, bytes| {
                bytes.resize(w * h * 2, 0);
                y16.signed_dn(Src::packed(&img.data, w, h, 1), bytes)
                    .is_ok()
            });
        }
        if queued {
            self.wake()?;
        }
        Ok(())
    }

    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
        let mode = self.mode_name();
        let (vw, vh) = (self.view.width as usize, self.view.height as usize);
        let card = &self.no_signal_view;
        let (yuyv, rgb24) = (&mut self.yuyv, &mut self.rgb24);
        let mut queued = Self::offer(&self.shared.view, mode, timestamp_us, |wire, bytes| {
            bytes.resize(vw * vh * wire.bytes_per_pixel(), 0);
            let conv = if wire == Wire::Rgb { rgb24 } else { yuyv };
            conv.grey8(Src::packed(card, vw, vh, 1), bytes).is_ok()
        });
        let data_card = &self.no_signal_data;
        queued |= Self::offer(&self.shared.data, mode, timestamp_us, |_, bytes| {
            bytes.clear();
            bytes.extend_from_slice(data_card);
            true
        });
        if queued {
            self.wake()?;
        }
        Ok(())
    }

    /// Streams a reader has started (view plus data).
    fn watchers(&mut self) -> Option<u32> {
        let n = |p: &Port| u32::from(p.wire().is_some());
        Some(n(&self.shared.view) + n(&self.shared.data))
    }

    fn set_mode(&mut self, mode: ModeId) {
        if self.mode != Some(mode) {
            self.mode = Some(mode);
            let _ = self.tx.send(Msg::Mode(mode.name()));
        }
    }
}

impl Drop for PipewireSink {
    fn drop(&mut self) {
        let _ = self.tx.send(Msg::Quit);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Serializes a pod object.
fn pod_bytes(object: Object) -> Result<Vec<u8>, String> {
    spa::pod::serialize::PodSerializer::serialize(
        std::io::Cursor::new(Vec::new()),
        &Value::Object(object),
    )
    .map(|(cursor, _)| cursor.into_inner())
    .map_err(|e| format!("serializing a SPA pod: {e:?}"))
}

/// The EnumFormats a stream offers: raw video at one size and rate, one
/// param per format in `wires` (preferred first), each with a plain format
/// Id, as PipeWire's V4L2 nodes enumerate them. WebRTC's PipeWire camera
/// (Chromium's `WebRtcPipeWireCamera`) skips a param whose format is a
/// Choice, and then lists no camera.
fn enum_formats(
    wires: &[Wire],
    width: u32,
    height: u32,
    frame_rate_hz: u32,
) -> Result<Vec<Vec<u8>>, String> {
    use spa::param::format::{FormatProperties, MediaSubtype, MediaType};
    wires
        .iter()
        .map(|w| {
            pod_bytes(spa::pod::object!(
                spa::utils::SpaTypes::ObjectParamFormat,
                spa::param::ParamType::EnumFormat,
                spa::pod::property!(FormatProperties::MediaType, Id, MediaType::Video),
                spa::pod::property!(FormatProperties::MediaSubtype, Id, MediaSubtype::Raw),
                spa::pod::property!(FormatProperties::VideoFormat, Id, w.spa()),
                spa::pod::property!(
                    FormatProperties::VideoSize,
                    Rectangle,
                    Rectangle { width, height }
                ),
                spa::pod::property!(
                    FormatProperties::VideoFramerate,
                    Fraction,
                    Fraction {
                        num: frame_rate_hz,
                        denom: 1
                    }
                ),
            ))
        })
        .collect()
}

/// Buffers (count, one plane of `size_bytes`) and the header metadata (PTS).
fn buffer_params(size_bytes: usize, stride_bytes: usize) -> Result<[Vec<u8>; 2], String> {
    use spa::sys;
    let int = |v: usize| Value::Int(i32::try_from(v).unwrap_or(i32::MAX));
    let (default, min, max) = BUFFERS;
    let buffers = Object {
        type_: sys::SPA_TYPE_OBJECT_ParamBuffers,
        id: sys::SPA_PARAM_Buffers,
        properties: vec![
            Property::new(
                sys::SPA_PARAM_BUFFERS_buffers,
                Value::Choice(ChoiceValue::Int(Choice(
                    ChoiceFlags::empty(),
                    ChoiceEnum::Range { default, min, max },
                ))),
            ),
            Property::new(sys::SPA_PARAM_BUFFERS_blocks, Value::Int(1)),
            Property::new(sys::SPA_PARAM_BUFFERS_size, int(size_bytes)),
            Property::new(sys::SPA_PARAM_BUFFERS_stride, int(stride_bytes)),
        ],
    };
    let meta = Object {
        type_: sys::SPA_TYPE_OBJECT_ParamMeta,
        id: sys::SPA_PARAM_Meta,
        properties: vec![
            Property::new(
                sys::SPA_PARAM_META_type,
                Value::Id(Id(sys::SPA_META_Header)),
            ),
            Property::new(
                sys::SPA_PARAM_META_size,
                int(std::mem::size_of::<sys::spa_meta_header>()),
            ),
        ],
    };
    Ok([pod_bytes(buffers)?, pod_bytes(meta)?])
}

/// The loop thread's view of one stream.
struct StreamState {
    name: &'static str,
    width: u32,
    height: u32,
    /// Negotiated format.
    wire: Option<Wire>,
    seq: u64,
    last_pts_ns: i64,
}

fn monotonic_ns() -> i64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() * 1_000_000_000 + t.tv_nsec())
        .unwrap_or(0)
}

/// Copies `port`'s pending frame into a free buffer of `stream` and queues it.
fn publish(stream: &pw::stream::Stream, port: &Port, state: &mut StreamState) {
    let Some(frame) = port.slot().pending.take() else {
        return;
    };
    let frame = Returned(frame, port);
    if state.wire != Some(frame.0.wire) {
        return;
    }
    // SAFETY: dequeue on the loop thread that owns the stream; a null result
    // (no free buffer: the reader holds them all) is checked below.
    let pwb = unsafe { stream.dequeue_raw_buffer() };
    if pwb.is_null() {
        return;
    }
    let bytes = &frame.0.bytes;
    let stride = state.width as usize * frame.0.wire.bytes_per_pixel();
    // PTS is the capture time (spa_meta_header.pts: ns, CLOCK_MONOTONIC),
    // as on the loopback node, so a reader can tell the frame's age; strictly
    // increasing per stream.
    let capture_ns = match frame.0.timestamp_us {
        0 => monotonic_ns(),
        us => i64::try_from(us.saturating_mul(1000)).unwrap_or(i64::MAX),
    };
    let pts_ns = capture_ns.max(state.last_pts_ns + 1);
    state.last_pts_ns = pts_ns;
    state.seq += 1;
    let mut written = 0;
    // SAFETY: `pwb` came from dequeue and is ours until queued; its spa_buffer,
    // data planes, chunks and metas are set up by PipeWire for the negotiated
    // Buffers/Meta params; MAP_BUFFERS maps `data` for `maxsize` bytes. We
    // write at most `maxsize` bytes and check every pointer for null.
    unsafe {
        let buf = (*pwb).buffer;
        if !buf.is_null() && (*buf).n_datas >= 1 && !(*buf).datas.is_null() {
            let d = &mut *(*buf).datas;
            if !d.data.is_null() && !d.chunk.is_null() {
                written = bytes.len().min(d.maxsize as usize);
                std::ptr::copy_nonoverlapping(bytes.as_ptr(), d.data.cast::<u8>(), written);
                let chunk = &mut *d.chunk;
                chunk.offset = 0;
                chunk.size = written as u32;
                chunk.stride = stride as i32;
                chunk.flags = 0;
            }
            let h = spa::sys::spa_buffer_find_meta_data(
                buf,
                spa::sys::SPA_META_Header,
                std::mem::size_of::<spa::sys::spa_meta_header>(),
            )
            .cast::<spa::sys::spa_meta_header>();
            if !h.is_null() {
                (*h).flags = 0;
                (*h).offset = 0;
                (*h).pts = pts_ns;
                (*h).dts_offset = 0;
                (*h).seq = state.seq;
            }
        }
    }
    if tracing::enabled!(target: FRAME_LOG, tracing::Level::TRACE) {
        tracing::trace!(
            target: FRAME_LOG,
            stream = state.name,
            format = frame.0.wire.name(),
            mode = frame.0.mode,
            seq = state.seq,
            pts_ns,
            capture_us = frame.0.timestamp_us,
            published_ns = monotonic_ns(),
            bytes = written,
            crc32 = format_args!("{:08x}", crc32fast::hash(&bytes[..written])),
            "published"
        );
    }
    // SAFETY: `pwb` was dequeued from this stream above and not queued yet.
    unsafe { stream.queue_raw_buffer(pwb) };
    port.published.fetch_add(1, Ordering::Relaxed);
}

/// Returns the frame's allocation to the slot when dropped.
struct Returned<'a>(Pending, &'a Port);

impl Drop for Returned<'_> {
    fn drop(&mut self) {
        let bytes = std::mem::take(&mut self.0.bytes);
        let mut slot = self.1.slot();
        if slot.spare.capacity() < bytes.capacity() {
            slot.spare = bytes;
        }
    }
}

/// Sets a stream's node description.
fn describe(stream: &pw::stream::Stream, description: &str) {
    let props = pw::properties::properties! { *pw::keys::NODE_DESCRIPTION => description };
    // SAFETY: the stream is alive and used on its loop thread; the dict is
    // only read during the call (PipeWire copies it).
    let r =
        unsafe { pw::sys::pw_stream_update_properties(stream.as_raw_ptr(), props.dict().as_raw()) };
    if r < 0 {
        tracing::debug!(
            "updating the node description of {}: error {r}",
            stream.name()
        );
    }
}

fn run_loop(
    spec: Spec,
    shared: Arc<Shared>,
    rx: pw::channel::Receiver<Msg>,
    ready: mpsc::Sender<Result<(), String>>,
) {
    pw::init();
    let ready = RefCell::new(Some(ready));
    let report = |r: Result<(), String>| {
        if let Some(tx) = ready.borrow_mut().take() {
            let _ = tx.send(r);
        }
    };
    if let Err(e) = serve(&spec, &shared, rx, &report) {
        shared.broken.store(true, Ordering::Relaxed);
        report(Err(e));
    }
    shared.view.streaming.store(0, Ordering::Release);
    shared.data.streaming.store(0, Ordering::Release);
}

/// Builds the loop, connects, creates both streams and runs until `Quit`.
fn serve(
    spec: &Spec,
    shared: &Arc<Shared>,
    rx: pw::channel::Receiver<Msg>,
    report: &dyn Fn(Result<(), String>),
) -> Result<(), String> {
    fn err(what: &'static str) -> impl Fn(pw::Error) -> String {
        move |e| format!("PipeWire: {what}: {e}")
    }
    let mainloop = pw::main_loop::MainLoopRc::new(None).map_err(err("creating the loop"))?;
    let context =
        pw::context::ContextRc::new(&mainloop, None).map_err(err("creating a context"))?;
    let core = context.connect_rc(None).map_err(|e| {
        let socket = std::env::var("PIPEWIRE_REMOTE").unwrap_or_else(|_| {
            std::env::var("XDG_RUNTIME_DIR")
                .map_or("(no XDG_RUNTIME_DIR)".into(), |d| format!("{d}/pipewire-0"))
        });
        format!("no PipeWire daemon reachable at {socket}: {e}")
    })?;
    let lost = {
        let (shared, mainloop) = (shared.clone(), mainloop.downgrade());
        core.add_listener_local()
            .error(move |id, _seq, res, message| {
                if id == pw::core::PW_ID_CORE {
                    tracing::warn!("PipeWire connection error {res}: {message}");
                    shared.broken.store(true, Ordering::Relaxed);
                    if let Some(l) = mainloop.upgrade() {
                        l.quit();
                    }
                }
            })
            .register()
    };

    let view = make_stream(
        &core,
        shared,
        StreamSpec {
            node: VIEW_NODE,
            description: view_description(spec.mode),
            camera: true,
            wires: &[Wire::Yuyv, Wire::Rgb],
            width: spec.view_width,
            height: spec.view_height,
            frame_rate_hz: spec.frame_rate_hz,
        },
        |s| &s.view,
    )?;
    let data = make_stream(
        &core,
        shared,
        StreamSpec {
            node: DATA_NODE,
            description: data_description(spec.mode),
            camera: false,
            wires: &[Wire::Y16],
            width: spec.data_width,
            height: spec.data_height,
            frame_rate_hz: spec.frame_rate_hz,
        },
        |s| &s.data,
    )?;

    let _receiver = {
        let (shared, weak) = (shared.clone(), mainloop.downgrade());
        let (view_stream, view_state) = (view.stream.clone(), view.state.clone());
        let (data_stream, data_state) = (data.stream.clone(), data.state.clone());
        rx.attach(mainloop.loop_(), move |msg| match msg {
            Msg::Wake => {
                shared.woken.store(false, Ordering::Release);
                for (stream, state, port) in [
                    (&view_stream, &view_state, &shared.view),
                    (&data_stream, &data_state, &shared.data),
                ] {
                    if port.slot().pending.is_none() {
                        continue;
                    }
                    if stream.is_driving() {
                        // process() publishes, in the graph's cycle.
                        let _ = stream.trigger_process();
                    } else {
                        publish(stream, port, &mut state.borrow_mut());
                    }
                }
            }
            Msg::Mode(mode) => {
                describe(&view_stream, &view_description(mode));
                describe(&data_stream, &data_description(mode));
            }
            Msg::Quit => {
                if let Some(l) = weak.upgrade() {
                    l.quit();
                }
            }
        })
    };
    tracing::info!(
        view = VIEW_NODE,
        data = DATA_NODE,
        "PipeWire nodes created (Video/Source, media.role Camera on the view)"
    );
    report(Ok(()));
    mainloop.run();
    drop(lost);
    Ok(())
}

struct StreamSpec {
    node: &'static str,
    description: String,
    /// Advertise as a camera (`media.role = Camera`).
    camera: bool,
    wires: &'static [Wire],
    width: u32,
    height: u32,
    frame_rate_hz: u32,
}

struct MadeStream {
    stream: pw::stream::StreamRc,
    state: Rc<RefCell<StreamState>>,
    _listener: pw::stream::StreamListener<()>,
}

fn make_stream(
    core: &pw::core::CoreRc,
    shared: &Arc<Shared>,
    spec: StreamSpec,
    port_of: fn(&Shared) -> &Port,
) -> Result<MadeStream, String> {
    let err = |e: pw::Error| format!("PipeWire stream {}: {e}", spec.node);
    let mut props = pw::properties::properties! {
        *pw::keys::MEDIA_TYPE => "Video",
        *pw::keys::MEDIA_CATEGORY => "Capture",
        *pw::keys::MEDIA_CLASS => "Video/Source",
        *pw::keys::NODE_NAME => spec.node,
        *pw::keys::NODE_DESCRIPTION => spec.description.as_str(),
        "node.nick" => "SDI camera",
    };
    if spec.camera {
        props.insert(*pw::keys::MEDIA_ROLE, "Camera");
    }
    let stream = pw::stream::StreamRc::new(core.clone(), spec.node, props).map_err(err)?;
    let state = Rc::new(RefCell::new(StreamState {
        name: spec.node,
        width: spec.width,
        height: spec.height,
        wire: None,
        seq: 0,
        last_pts_ns: 0,
    }));
    let (s1, s2, s3) = (shared.clone(), shared.clone(), shared.clone());
    let (st1, st2, st3) = (state.clone(), state.clone(), state.clone());
    let listener = stream
        .add_local_listener_with_user_data(())
        .state_changed(move |_, _, old, new| {
            let port = port_of(&s1);
            let st = st1.borrow();
            let streaming = matches!(new, pw::stream::StreamState::Streaming);
            let code = match (streaming, st.wire) {
                (true, Some(w)) => w as u8,
                _ => 0,
            };
            port.streaming.store(code, Ordering::Release);
            match &new {
                pw::stream::StreamState::Streaming => {
                    tracing::info!(
                        node = st.name,
                        format = st.wire.map_or("?", Wire::name),
                        "PipeWire reader streaming"
                    )
                }
                pw::stream::StreamState::Error(e) => {
                    tracing::warn!(node = st.name, "PipeWire stream error: {e}")
                }
                _ if matches!(old, pw::stream::StreamState::Streaming) => {
                    tracing::info!(node = st.name, "PipeWire reader stopped")
                }
                _ => tracing::debug!(node = st.name, "PipeWire stream {old:?} -> {new:?}"),
            }
        })
        .param_changed(move |stream, _, id, param| {
            let Some(param) = param else { return };
            if id != spa::param::ParamType::Format.as_raw() {
                return;
            }
            let mut info = spa::param::video::VideoInfoRaw::new();
            if info.parse(param).is_err() {
                return;
            }
            let mut st = st2.borrow_mut();
            st.wire = Wire::from_spa(info.format());
            let Some(wire) = st.wire else {
                tracing::warn!(
                    node = st.name,
                    "PipeWire negotiated an unexpected format {:?}",
                    info.format()
                );
                return;
            };
            let stride = st.width as usize * wire.bytes_per_pixel();
            let size = stride * st.height as usize;
            match buffer_params(size, stride) {
                Ok(pods) => {
                    let mut params: Vec<&Pod> =
                        pods.iter().filter_map(|b| Pod::from_bytes(b)).collect();
                    if let Err(e) = stream.update_params(&mut params) {
                        tracing::warn!(node = st.name, "PipeWire buffer parameters: {e}");
                    }
                }
                Err(e) => tracing::warn!(node = st.name, "{e}"),
            }
            // A format change while streaming: the new format counts from now.
            let port = port_of(&s2);
            if port.streaming.load(Ordering::Acquire) != 0 {
                port.streaming.store(wire as u8, Ordering::Release);
            }
        })
        .process(move |stream, _| publish(stream, port_of(&s3), &mut st3.borrow_mut()))
        .register()
        .map_err(err)?;
    let formats = enum_formats(spec.wires, spec.width, spec.height, spec.frame_rate_hz)?;
    let mut pods = formats
        .iter()
        .map(|f| Pod::from_bytes(f).ok_or("PipeWire: invalid format pod"))
        .collect::<Result<Vec<&Pod>, _>>()?;
    stream
        .connect(
            spa::utils::Direction::Output,
            None,
            pw::stream::StreamFlags::DRIVER | pw::stream::StreamFlags::MAP_BUFFERS,
            &mut pods,
        )
        .map_err(err)?;
    Ok(MadeStream {
        stream,
        state,
        _listener: listener,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_codes_round_trip() {
        for w in [Wire::Yuyv, Wire::Rgb, Wire::Y16] {
            assert_eq!(Wire::from_code(w as u8), Some(w));
            assert_eq!(Wire::from_spa(w.spa()), Some(w));
        }
        assert_eq!(Wire::from_code(0), None);
    }

    #[test]
    fn params_serialize() {
        let f = enum_formats(&[Wire::Yuyv, Wire::Rgb], 640, 480, 30).unwrap();
        assert_eq!(f.len(), 2, "one EnumFormat per format");
        assert!(f.iter().all(|p| Pod::from_bytes(p).is_some()));
        let f = enum_formats(&[Wire::Y16], 320, 240, 30).unwrap();
        assert_eq!(f.len(), 1);
        assert!(Pod::from_bytes(&f[0]).is_some());
        for p in buffer_params(640 * 480 * 2, 1280).unwrap() {
            assert!(Pod::from_bytes(&p).is_some());
        }
    }
}
