//! The camera process's PipeWire nodes. Two output streams: the view
//! (`Video/Source`, `media.role = Camera`, YUYV or RGB at the v4l2loopback
//! view size) and the raw data (`Video/Source`, Y16 at the sensor size,
//! signed DN offset by 32768, no camera role so camera pickers skip it).
//!
//! PipeWire's loop runs on its own thread ("sdi-camera-pw"). Frames arrive
//! already rendered, in the format a reader negotiated, into a one-frame
//! slot per stream, and wake the loop; the loop copies the slot into a
//! PipeWire buffer (dropping the frame when the reader holds every buffer).
//! Frames therefore never wait on PipeWire or its readers.
// The PipeWire edge: buffers dequeued raw (to write the header meta) and
// one stream call the crate does not wrap.
#![allow(unsafe_code)]

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use pipewire as pw;
use pw::spa;
use sdi_core::mode::ModeId;
use sdi_core::view::{no_signal_card, PixelFormat};
use spa::buffer::Data;
use spa::param::video::VideoFormat;
use spa::pod::{ChoiceValue, Object, Pod, Property, Value};
use spa::utils::{Choice, ChoiceEnum, ChoiceFlags, Fraction, Id, Rectangle};

use sdi_camera_link::{Port, Spec, State, Wire, FRAME_LOG};

/// Why the nodes could not be made; the messages are what the starting sdid
/// reports.
#[derive(Debug, thiserror::Error)]
pub enum NodesError {
    #[error("starting the PipeWire thread: {0}")]
    Thread(#[source] std::io::Error),
    #[error("PipeWire did not answer within {} s", CONNECT_TIMEOUT.as_secs())]
    Timeout,
    #[error("PipeWire: {what}: {source}")]
    Pipewire {
        what: &'static str,
        #[source]
        source: pw::Error,
    },
    #[error("no PipeWire daemon reachable at {socket}: {source}")]
    Unreachable {
        socket: String,
        #[source]
        source: pw::Error,
    },
    #[error("PipeWire stream {node}: {source}")]
    Stream {
        node: String,
        #[source]
        source: pw::Error,
    },
    #[error("serializing a SPA pod: {0:?}")]
    Pod(#[source] spa::pod::serialize::GenError),
    #[error("PipeWire: invalid format pod")]
    InvalidPod,
}

/// How long [`Nodes::open`] waits for the PipeWire thread to connect.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// The node property the session manager reads for how long a node may
/// idle before it suspends it (0: never), WirePlumber 0.4 and 0.5 alike.
const SUSPEND_TIMEOUT_KEY: &str = "session.suspend-timeout-seconds";
/// Buffers per stream: the reader may hold some while we fill another.
const BUFFERS: (i32, i32, i32) = (4, 2, 8);

fn spa_format(w: Wire) -> VideoFormat {
    match w {
        Wire::Yuyv => VideoFormat::YUY2,
        Wire::Rgb => VideoFormat::RGB,
        Wire::Y16 => VideoFormat::GRAY16_LE,
    }
}

/// The view's pixel format of a wire format.
fn pixel_format(w: Wire) -> PixelFormat {
    match w {
        Wire::Yuyv => PixelFormat::Yuyv,
        Wire::Rgb => PixelFormat::Rgb24,
        Wire::Y16 => PixelFormat::Y16,
    }
}

fn wire_of(f: VideoFormat) -> Option<Wire> {
    Wire::ALL.into_iter().find(|w| spa_format(*w) == f)
}

/// A rendered frame waiting for the PipeWire thread.
struct Pending {
    bytes: Vec<u8>,
    wire: Wire,
    mode: &'static str,
    /// Capture time (CLOCK_MONOTONIC, sdid's publish clock); 0: unknown,
    /// stamped when published.
    timestamp_us: u64,
}

#[derive(Default)]
struct Slot {
    pending: Option<Pending>,
    /// The last consumed frame's allocation, reused.
    spare: Vec<u8>,
}

/// One stream as both threads see it.
struct SharedStream {
    /// `Wire` code negotiated while a reader streams; 0 when nobody does.
    streaming: AtomicU8,
    slot: Mutex<Slot>,
    /// Buffers handed to PipeWire.
    published: AtomicU64,
}

impl SharedStream {
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
    view: SharedStream,
    data: SharedStream,
    /// A wake-up is queued on the loop's channel (keeps the channel at one message).
    woken: AtomicBool,
    /// Set by the loop when the PipeWire connection is lost.
    broken: AtomicBool,
}

impl Shared {
    fn stream(&self, port: Port) -> &SharedStream {
        match port {
            Port::View => &self.view,
            Port::Data => &self.data,
        }
    }
}

enum Msg {
    /// New frames in the slots.
    Wake,
    /// The mode changed: new node descriptions.
    Mode(&'static str),
    Quit,
}

/// The camera's nodes, fed from any thread through `&self`.
pub struct Nodes {
    shared: Arc<Shared>,
    tx: pw::channel::Sender<Msg>,
    thread: Option<JoinHandle<()>>,
    spec: Spec,
    mode: Mutex<ModeId>,
    /// The "no signal" card, rendered once: at the view size in each wire
    /// format a reader may stream, and in Y16 at the sensor size.
    no_signal_view: Vec<(Wire, Vec<u8>)>,
    no_signal_data: Vec<u8>,
}

impl Nodes {
    /// Connects to the PipeWire daemon of this user (`$PIPEWIRE_REMOTE`, else
    /// `$XDG_RUNTIME_DIR/pipewire-0`) and creates both nodes; fails when no
    /// daemon answers.
    pub fn open(spec: &Spec) -> Result<Self, NodesError> {
        let shared = Arc::new(Shared {
            view: SharedStream::new(),
            data: SharedStream::new(),
            woken: AtomicBool::new(false),
            broken: AtomicBool::new(false),
        });
        let (tx, rx) = pw::channel::channel::<Msg>();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), NodesError>>();
        let loop_shared = shared.clone();
        let loop_spec = spec.clone();
        let thread = std::thread::Builder::new()
            .name("sdi-camera-pw".into())
            .spawn(move || run_loop(loop_spec, loop_shared, rx, ready_tx))
            .map_err(NodesError::Thread)?;
        match ready_rx.recv_timeout(CONNECT_TIMEOUT) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let _ = thread.join();
                return Err(e);
            }
            Err(_) => {
                let _ = tx.send(Msg::Quit);
                return Err(NodesError::Timeout);
            }
        }
        let card =
            |w: u32, h: u32, wire: Wire| no_signal_card(pixel_format(wire), w as usize, h as usize);
        let no_signal_view = Wire::ALL
            .iter()
            .map(|&wire| (wire, card(spec.view_width, spec.view_height, wire)))
            .collect();
        let no_signal_data = card(spec.data_width, spec.data_height, Wire::Y16);
        Ok(Self {
            shared,
            tx,
            thread: Some(thread),
            spec: spec.clone(),
            mode: Mutex::new(spec.mode),
            no_signal_view,
            no_signal_data,
        })
    }

    pub fn spec(&self) -> &Spec {
        &self.spec
    }

    /// What readers stream, and buffers published so far.
    pub fn state(&self) -> State {
        State {
            view: self.shared.view.wire(),
            data: self.shared.data.wire(),
            view_published: self.shared.view.published.load(Ordering::Relaxed),
            data_published: self.shared.data.published.load(Ordering::Relaxed),
        }
    }

    /// True once the PipeWire connection is lost.
    pub fn broken(&self) -> bool {
        self.shared.broken.load(Ordering::Relaxed)
    }

    fn mode(&self) -> ModeId {
        *self.mode.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Puts a frame of `wire` into `port`'s slot, replacing one the loop has
    /// not taken yet, when a reader streams `wire` there; `fill` writes the
    /// bytes into the given buffer. False (and `fill` not called) when
    /// nobody streams that format.
    pub fn offer<E>(
        &self,
        port: Port,
        wire: Wire,
        timestamp_us: u64,
        fill: impl FnOnce(&mut Vec<u8>) -> Result<(), E>,
    ) -> Result<bool, E> {
        let port_state = self.shared.stream(port);
        if port_state.wire() != Some(wire) {
            return Ok(false);
        }
        let mut bytes = std::mem::take(&mut port_state.slot().spare);
        if let Err(e) = fill(&mut bytes) {
            port_state.slot().spare = bytes;
            return Err(e);
        }
        let mut slot = port_state.slot();
        if let Some(old) = slot.pending.replace(Pending {
            bytes,
            wire,
            mode: self.mode().name(),
            timestamp_us,
        }) {
            slot.spare = old.bytes;
        }
        drop(slot);
        self.wake();
        Ok(true)
    }

    /// Publishes the "no signal" card on both nodes, stamped `timestamp_us`.
    pub fn no_signal(&self, timestamp_us: u64) {
        if let Some(wire) = self.shared.view.wire() {
            if let Some((_, card)) = self.no_signal_view.iter().find(|(w, _)| *w == wire) {
                let _ = self.offer(Port::View, wire, timestamp_us, copy(card));
            }
        }
        let _ = self.offer(
            Port::Data,
            Wire::Y16,
            timestamp_us,
            copy(&self.no_signal_data),
        );
    }

    /// New node descriptions for `mode`.
    pub fn set_mode(&self, mode: ModeId) {
        let mut m = self.mode.lock().unwrap_or_else(|e| e.into_inner());
        if *m != mode {
            *m = mode;
            let _ = self.tx.send(Msg::Mode(mode.name()));
        }
    }

    fn wake(&self) {
        if !self.shared.woken.swap(true, Ordering::AcqRel) && self.tx.send(Msg::Wake).is_err() {
            self.shared.broken.store(true, Ordering::Relaxed);
        }
    }
}

/// A frame filler that copies `card`.
fn copy(card: &[u8]) -> impl FnOnce(&mut Vec<u8>) -> Result<(), ()> + '_ {
    move |bytes| {
        bytes.clear();
        bytes.extend_from_slice(card);
        Ok(())
    }
}

impl Drop for Nodes {
    fn drop(&mut self) {
        let _ = self.tx.send(Msg::Quit);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Serializes a pod object.
fn pod_bytes(object: Object) -> Result<Vec<u8>, NodesError> {
    spa::pod::serialize::PodSerializer::serialize(
        std::io::Cursor::new(Vec::new()),
        &Value::Object(object),
    )
    .map(|(cursor, _)| cursor.into_inner())
    .map_err(NodesError::Pod)
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
) -> Result<Vec<Vec<u8>>, NodesError> {
    use spa::param::format::{FormatProperties, MediaSubtype, MediaType};
    wires
        .iter()
        .map(|w| {
            pod_bytes(spa::pod::object!(
                spa::utils::SpaTypes::ObjectParamFormat,
                spa::param::ParamType::EnumFormat,
                spa::pod::property!(FormatProperties::MediaType, Id, MediaType::Video),
                spa::pod::property!(FormatProperties::MediaSubtype, Id, MediaSubtype::Raw),
                spa::pod::property!(FormatProperties::VideoFormat, Id, spa_format(*w)),
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
fn buffer_params(size_bytes: usize, stride_bytes: usize) -> Result<[Vec<u8>; 2], NodesError> {
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
    name: String,
    width: u32,
    height: u32,
    /// Negotiated format.
    wire: Option<Wire>,
    seq: u64,
    last_pts_ns: i64,
}

/// CLOCK_MONOTONIC now, microseconds (0 if the clock cannot be read): the
/// clock of the link's timestamps.
pub fn monotonic_now_us() -> u64 {
    u64::try_from(monotonic_ns() / 1000).unwrap_or(0)
}

fn monotonic_ns() -> i64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() * 1_000_000_000 + t.tv_nsec())
        .unwrap_or(0)
}

/// Copies `port`'s pending frame into a free buffer of `stream` and queues it.
fn publish(stream: &pw::stream::Stream, port: &SharedStream, state: &mut StreamState) {
    let Some(frame) = port.slot().pending.take() else {
        return;
    };
    let frame = Returned(frame, port);
    if state.wire != Some(frame.0.wire) {
        return;
    }
    // Taken raw, not as the crate's `Buffer`: its `find_meta` gives the
    // header metadata read-only, and the PTS has to be written there.
    // SAFETY: dequeue on the loop thread that owns the stream; a null result
    // (no free buffer: the reader holds them all) is checked below.
    let pwb = unsafe { stream.dequeue_raw_buffer() };
    if pwb.is_null() {
        return;
    }
    // SAFETY: `pwb` came from dequeue and is ours until queued below.
    let buf = unsafe { (*pwb).buffer };
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
    if !buf.is_null() {
        // SAFETY: PipeWire set `buf` up for the negotiated Buffers param:
        // `datas` holds `n_datas` planes, valid and ours while we hold `pwb`.
        // libspa's `Data` is `repr(transparent)` over `spa_data`, the cast
        // its own `Buffer::datas_mut` makes.
        let planes: &mut [Data] = unsafe {
            let n = (*buf).n_datas as usize;
            match (*buf).datas.cast::<Data>() {
                d if d.is_null() || n == 0 => &mut [],
                d => std::slice::from_raw_parts_mut(d, n),
            }
        };
        if let Some(plane) = planes.first_mut() {
            written = fill_plane(plane, bytes, stride);
        }
        // SAFETY: `buf` is valid while we hold `pwb`; PipeWire's lookup
        // returns a header of at least the size asked for, or null.
        unsafe { stamp_header(buf, pts_ns, state.seq) };
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

/// Copies `bytes` into a mapped plane (MAP_BUFFERS maps it for `maxsize`
/// bytes) and describes them in its chunk; the bytes written.
fn fill_plane(plane: &mut Data, bytes: &[u8], stride_bytes: usize) -> usize {
    // `chunk_mut` asserts a chunk; PipeWire gives every plane one.
    if plane.as_raw().chunk.is_null() {
        return 0;
    }
    let Some(dst) = plane.data() else {
        return 0;
    };
    let written = bytes.len().min(dst.len());
    dst[..written].copy_from_slice(&bytes[..written]);
    let chunk = plane.chunk_mut();
    *chunk.offset_mut() = 0;
    *chunk.size_mut() = written as u32;
    *chunk.stride_mut() = stride_bytes as i32;
    written
}

/// Writes the frame's PTS and sequence number into the buffer's header
/// metadata (the Meta param asks for one); the safe API only reads it.
///
/// # Safety
///
/// `buf` is a valid `spa_buffer` of a dequeued, not yet queued, buffer.
unsafe fn stamp_header(buf: *mut spa::sys::spa_buffer, pts_ns: i64, seq: u64) {
    // SAFETY: the caller's contract; the lookup checks the header's size.
    let h = unsafe {
        spa::sys::spa_buffer_find_meta_data(
            buf,
            spa::sys::SPA_META_Header,
            std::mem::size_of::<spa::sys::spa_meta_header>(),
        )
    }
    .cast::<spa::sys::spa_meta_header>();
    // SAFETY: non-null: a header of the asked size inside the buffer's metas.
    if let Some(h) = unsafe { h.as_mut() } {
        h.flags = 0;
        h.offset = 0;
        h.pts = pts_ns;
        h.dts_offset = 0;
        h.seq = seq;
    }
}

/// Returns the frame's allocation to the slot when dropped.
struct Returned<'a>(Pending, &'a SharedStream);

impl Drop for Returned<'_> {
    fn drop(&mut self) {
        let bytes = std::mem::take(&mut self.0.bytes);
        let mut slot = self.1.slot();
        if slot.spare.capacity() < bytes.capacity() {
            slot.spare = bytes;
        }
    }
}

/// Sets a stream's node description (raw: the crate's `Stream` has no
/// `update_properties`).
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
    ready: mpsc::Sender<Result<(), NodesError>>,
) {
    pw::init();
    let ready = RefCell::new(Some(ready));
    let report = |r: Result<(), NodesError>| {
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
    report: &dyn Fn(Result<(), NodesError>),
) -> Result<(), NodesError> {
    fn err(what: &'static str) -> impl Fn(pw::Error) -> NodesError {
        move |source| NodesError::Pipewire { what, source }
    }
    let mainloop = pw::main_loop::MainLoopRc::new(None).map_err(err("creating the loop"))?;
    let context =
        pw::context::ContextRc::new(&mainloop, None).map_err(err("creating a context"))?;
    let core = context.connect_rc(None).map_err(|source| {
        let socket = std::env::var("PIPEWIRE_REMOTE").unwrap_or_else(|_| {
            std::env::var("XDG_RUNTIME_DIR")
                .map_or("(no XDG_RUNTIME_DIR)".into(), |d| format!("{d}/pipewire-0"))
        });
        NodesError::Unreachable { socket, source }
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

    let names = spec.names();
    let view = make_stream(
        &core,
        shared,
        StreamSpec {
            node: names.view_node(),
            nick: names.label(),
            description: names.view_description(spec.mode.name()),
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
            node: names.data_node(),
            nick: names.label(),
            description: names.data_description(spec.mode.name()),
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
        let spec = spec.clone();
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
                describe(&view_stream, &spec.names().view_description(mode));
                describe(&data_stream, &spec.names().data_description(mode));
            }
            Msg::Quit => {
                if let Some(l) = weak.upgrade() {
                    l.quit();
                }
            }
        })
    };
    tracing::info!(
        view = names.view_node(),
        data = names.data_node(),
        "PipeWire nodes created (Video/Source, media.role Camera on the view)"
    );
    report(Ok(()));
    mainloop.run();
    drop(lost);
    Ok(())
}

struct StreamSpec {
    node: String,
    /// The camera's name without its mode ("SDI camera SERIAL").
    nick: String,
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
    port_of: fn(&Shared) -> &SharedStream,
) -> Result<MadeStream, NodesError> {
    let err = |source: pw::Error| NodesError::Stream {
        node: spec.node.clone(),
        source,
    };
    let mut props = pw::properties::properties! {
        *pw::keys::MEDIA_TYPE => "Video",
        *pw::keys::MEDIA_CATEGORY => "Capture",
        *pw::keys::MEDIA_CLASS => "Video/Source",
        *pw::keys::NODE_NAME => spec.node.as_str(),
        *pw::keys::NODE_DESCRIPTION => spec.description.as_str(),
        "node.nick" => spec.nick.as_str(),
        // Never suspended by the session manager (WirePlumber suspends a
        // node idle for 5 s): a suspend that lands while the next reader's
        // link allocates buffers fails that link ("Buffer allocation
        // failed" on PipeWire 1.4: a browser that closes its probe stream
        // and opens the camera again seconds later). A node of this process
        // holds no device to power down.
        SUSPEND_TIMEOUT_KEY => "0",
    };
    if spec.camera {
        props.insert(*pw::keys::MEDIA_ROLE, "Camera");
    }
    let stream = pw::stream::StreamRc::new(core.clone(), &spec.node, props).map_err(err)?;
    let state = Rc::new(RefCell::new(StreamState {
        name: spec.node.clone(),
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
            st.wire = wire_of(info.format());
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
        .map(|f| Pod::from_bytes(f).ok_or(NodesError::InvalidPod))
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
        for w in Wire::ALL {
            assert_eq!(Wire::from_code(w as u8), Some(w));
            assert_eq!(wire_of(spa_format(w)), Some(w));
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
