//! The link between sdid and its PipeWire camera process: a Unix stream
//! socket in `$XDG_RUNTIME_DIR`, one sdid at a time. Both sides use this one
//! definition.
//!
//! One camera process per camera: a lone camera's socket, lock and nodes
//! have the plain names ([`SOCKET_NAME`], [`VIEW_NODE`], ...); each of
//! several cameras is named by its serial ([`Spec::camera`], [`Names`]):
//! `sdi-camera-SERIAL.sock`, node `sdi-camera-SERIAL`.
//!
//! Each message is a 16-byte header (kind, port, wire format, a payload
//! length and a timestamp, little-endian) and a payload. Written by hand:
//! frames are large byte payloads copied once into the camera's slot, which a
//! general serializer would copy again.
//!
//! sdid to camera: `Hello` (the camera's [`Spec`]), `Frame` (rendered bytes
//! in the format a reader negotiated), `NoSignal`, `Mode`, `Quit`.
//! Camera to sdid: `Ready` or `Refused` (answering `Hello`), and `State`
//! (which formats readers stream, buffers published) whenever it changes.
#![forbid(unsafe_code)]

use std::fmt;
use std::io::{self, Read, Write};
use std::path::PathBuf;
use std::str::FromStr;

use sdi_core::mode::ModeId;
pub use sdi_core::serial::names_a_file;

/// File name of the (lone camera's) socket in `$XDG_RUNTIME_DIR`.
pub const SOCKET_NAME: &str = "sdi-camera.sock";
/// File name of the lock the running camera process holds.
pub const LOCK_NAME: &str = "sdi-camera.lock";
/// The camera program's file name: sdid runs `sdi-pipewire-camera SPEC`
/// (the [`Spec`] as its only argument).
pub const CAMERA_PROGRAM: &str = "sdi-pipewire-camera";
/// Where a package installs it, relative to the directory holding sdid.
pub const CAMERA_LIBEXEC: &str = "../libexec/sdi";
/// The Debian packages that build the camera program from source.
pub const CAMERA_BUILD_PACKAGES: &str = "libpipewire-0.3-dev libspa-0.2-dev clang libclang-dev";

/// Where sdid (and `sdictl doctor`) look for the camera program, given the
/// directory of sdid's executable: beside it (a build tree, `make
/// install`), then `../libexec/sdi/` (the package). The first that is a
/// file is the one.
pub fn camera_candidates(bin_dir: &std::path::Path) -> [PathBuf; 2] {
    [
        bin_dir.join(CAMERA_PROGRAM),
        bin_dir.join(CAMERA_LIBEXEC).join(CAMERA_PROGRAM),
    ]
}
/// The system service's feed socket, where the camera processes of users'
/// sessions (`sdi-pipewire-camera --system-feed`, the user unit
/// `sdi-pipewire-camera.service`) connect to the system sdid, which runs
/// as root without a PipeWire of its own: in sdid.service's
/// `RuntimeDirectory=sdi`, so `root:sdi` 0750, the socket 0660, and only
/// members of the group sdi (who may control the camera anyway) reach it.
/// The camera takes frames there only from a server running as root
/// (SO_PEERCRED), so no other user can feed it; on this connection sdid
/// speaks first (Hello), exactly as on a camera's own socket.
pub const SYSTEM_FEED_NAME: &str = "camera-feed.sock";
/// The stem of every feed socket's name: `camera-feed.sock` (a lone
/// camera) and `camera-feed-SERIAL.sock` ([`Names::system_feed`]).
pub const SYSTEM_FEED_STEM: &str = "camera-feed";
/// The system service's runtime directory (`RuntimeDirectory=sdi`).
pub const SYSTEM_RUNTIME_DIR: &str = "/run/sdi";
/// The camera's command-line flag for the feeds, optionally followed by a
/// directory (default [`SYSTEM_RUNTIME_DIR`]), whose every feed socket it
/// serves ([`system_feed_camera`]), or by one socket's path.
pub const SYSTEM_FEED_FLAG: &str = "--system-feed";

/// The camera a feed socket's file name names: `Some(None)` for
/// [`SYSTEM_FEED_NAME`], `Some(Some(serial))` for `camera-feed-SERIAL.sock`,
/// `None` for any other file.
pub fn system_feed_camera(file_name: &str) -> Option<Option<String>> {
    let rest = file_name
        .strip_prefix(SYSTEM_FEED_STEM)?
        .strip_suffix(".sock")?;
    match rest {
        "" => Some(None),
        r => r
            .strip_prefix('-')
            .filter(|s| names_a_file(s))
            .map(|s| Some(s.to_owned())),
    }
}

/// How long the camera outlives sdid while no reader streams.
pub const LINGER: std::time::Duration = std::time::Duration::from_secs(30);
/// Node name of the (lone camera's) view stream (what `pipewiresrc
/// target-object=` takes).
pub const VIEW_NODE: &str = "sdi-camera";
/// Node name of the (lone camera's) raw Y16 data stream.
pub const DATA_NODE: &str = "sdi-camera-data";
/// `tracing` target of the per-frame log (CRC-32 of each published buffer),
/// enabled with `RUST_LOG=sdid::pipewire::frames=trace`.
pub const FRAME_LOG: &str = "sdid::pipewire::frames";

/// Whether `node` is one of SDI's camera nodes (any camera's).
pub fn is_camera_node(node: &str) -> bool {
    [VIEW_NODE, DATA_NODE].iter().any(|base| {
        node.strip_prefix(base)
            .is_some_and(|rest| rest.is_empty() || rest.starts_with('-'))
    })
}

/// The names of one camera's socket, lock and nodes: the plain names for
/// a lone camera (`camera` `None`), each with `-SERIAL` for one of several.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Names<'a> {
    pub camera: Option<&'a str>,
}

impl Names<'_> {
    /// `base` for a lone camera, `base-SERIAL` for one of several.
    fn named(&self, base: &str) -> String {
        match self.camera {
            Some(c) => format!("{base}-{c}"),
            None => base.to_owned(),
        }
    }

    /// File name of the socket in `$XDG_RUNTIME_DIR`.
    pub fn socket(&self) -> String {
        self.named("sdi-camera") + ".sock"
    }

    /// File name of the lock the running camera process holds.
    pub fn lock(&self) -> String {
        self.named("sdi-camera") + ".lock"
    }

    /// The system service's feed socket in its runtime directory.
    pub fn system_feed(&self) -> String {
        self.named(SYSTEM_FEED_STEM) + ".sock"
    }

    /// Node name of the view stream.
    pub fn view_node(&self) -> String {
        self.named(VIEW_NODE)
    }

    /// Node name of the raw Y16 data stream.
    pub fn data_node(&self) -> String {
        self.named(DATA_NODE)
    }

    /// The node description readers show, e.g. "SDI camera (depth-edge)"
    /// or "SDI camera sim-1 (depth-edge)".
    pub fn view_description(&self, mode: &str) -> String {
        format!("{} ({mode})", self.label())
    }

    /// The data node's description.
    pub fn data_description(&self, mode: &str) -> String {
        format!("{} raw data, Y16 DN+32768 ({mode})", self.label())
    }

    /// The camera's name for people: "SDI camera" or "SDI camera SERIAL"
    /// (the node's nick; as the loopback node's label, camera_plan.rs).
    pub fn label(&self) -> String {
        match self.camera {
            Some(c) => format!("SDI camera {c}"),
            None => "SDI camera".into(),
        }
    }
}
/// The camera process's first line on stdout: serving.
pub const READY_LINE: &str = "ready";
/// ... or: another camera process runs (connect to it).
pub const BUSY_LINE: &str = "busy";
/// ... or this prefix and why it failed.
pub const ERROR_PREFIX: &str = "error: ";
/// Largest payload accepted (a 4096x4096 RGB frame is 48 MiB).
const MAX_PAYLOAD: u32 = 64 << 20;
const HEADER_BYTES: usize = 16;

/// `$XDG_RUNTIME_DIR`, where the socket and lock live (private to the user).
pub fn runtime_dir() -> Result<PathBuf, String> {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(d) if !d.is_empty() => Ok(PathBuf::from(d)),
        _ => Err("XDG_RUNTIME_DIR is not set: no user session for a PipeWire camera".into()),
    }
}

/// Pixel formats on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    Yuyv = 1,
    Rgb = 2,
    Y16 = 3,
}

impl Wire {
    pub const ALL: [Wire; 3] = [Wire::Yuyv, Wire::Rgb, Wire::Y16];

    pub fn from_code(c: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|w| *w as u8 == c)
    }

    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Wire::Yuyv | Wire::Y16 => 2,
            Wire::Rgb => 3,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Wire::Yuyv => "YUYV",
            Wire::Rgb => "RGB",
            Wire::Y16 => "Y16",
        }
    }
}

/// The camera's two nodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    /// `sdi-camera`: YUYV or RGB at the view size.
    View = 0,
    /// `sdi-camera-data`: Y16 at the sensor size.
    Data = 1,
}

/// What the camera process publishes: sizes, rate, the mode it starts in
/// and which camera it is. Text form `VIEWWxVIEWH,DATAWxDATAH,FPS,MODE`
/// for a lone camera, `...,MODE,SERIAL` for one of several (its command
/// line).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Spec {
    pub view_width: u32,
    pub view_height: u32,
    pub data_width: u32,
    pub data_height: u32,
    pub frame_rate_hz: u32,
    pub mode: ModeId,
    /// One of several cameras: its serial (one that
    /// [names a file](names_a_file)), which names its socket, lock and
    /// nodes; `None`: the lone camera.
    pub camera: Option<String>,
}

impl Spec {
    /// The names of this camera's socket, lock and nodes.
    pub fn names(&self) -> Names<'_> {
        Names {
            camera: self.camera.as_deref(),
        }
    }

    /// Same nodes (sizes and rate; the mode may differ).
    pub fn same_nodes(&self, other: &Spec) -> bool {
        Spec {
            mode: self.mode,
            ..other.clone()
        } == *self
    }
}

impl fmt::Display for Spec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}x{},{}x{},{},{}",
            self.view_width,
            self.view_height,
            self.data_width,
            self.data_height,
            self.frame_rate_hz,
            self.mode.name()
        )?;
        match &self.camera {
            Some(c) => write!(f, ",{c}"),
            None => Ok(()),
        }
    }
}

impl FromStr for Spec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("camera spec {s:?}: expected WxH,WxH,FPS,MODE[,SERIAL]");
        let parts: Vec<&str> = s.split(',').collect();
        let (view, data, fps, mode, camera) = match parts[..] {
            [view, data, fps, mode] => (view, data, fps, mode, None),
            [view, data, fps, mode, c] if names_a_file(c) => {
                (view, data, fps, mode, Some(c.to_owned()))
            }
            _ => return Err(bad()),
        };
        let size = |p: &str| -> Result<(u32, u32), String> {
            let (w, h) = p.split_once('x').ok_or_else(bad)?;
            let n = |v: &str| match v.parse::<u32>() {
                Ok(n @ 1..=16384) => Ok(n),
                _ => Err(bad()),
            };
            Ok((n(w)?, n(h)?))
        };
        let ((view_width, view_height), (data_width, data_height)) = (size(view)?, size(data)?);
        let frame_rate_hz = match fps.parse::<u32>() {
            Ok(f @ 1..=240) => f,
            _ => return Err(bad()),
        };
        let mode = mode
            .parse::<ModeId>()
            .map_err(|e| format!("camera spec {s:?}: {e}"))?;
        Ok(Spec {
            view_width,
            view_height,
            data_width,
            data_height,
            frame_rate_hz,
            mode,
            camera,
        })
    }
}

/// What readers stream and how many buffers went out, per port.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct State {
    pub view: Option<Wire>,
    pub data: Option<Wire>,
    pub view_published: u64,
    pub data_published: u64,
}

/// A message's header; a `Frame`'s bytes follow it on the socket.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Message {
    Hello(Spec),
    /// `len` bytes of `wire` for `port`, captured at `timestamp_us`
    /// (CLOCK_MONOTONIC); read them with [`read_payload`].
    Frame {
        port: Port,
        wire: Wire,
        timestamp_us: u64,
        len: usize,
    },
    NoSignal {
        timestamp_us: u64,
    },
    Mode(ModeId),
    Quit,
    Ready,
    Refused(String),
    State(State),
}

/// A broken or hostile link.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("camera link: {0}")]
    Io(#[from] io::Error),
    #[error("camera link: bad message: {0}")]
    Bad(String),
}

const HELLO: u8 = 1;
const FRAME: u8 = 2;
const NO_SIGNAL: u8 = 3;
const MODE: u8 = 4;
const QUIT: u8 = 5;
const READY: u8 = 16;
const REFUSED: u8 = 17;
const STATE: u8 = 18;

fn header(kind: u8, port: u8, wire: u8, len: usize, stamp: u64) -> [u8; HEADER_BYTES] {
    let mut h = [0u8; HEADER_BYTES];
    h[0] = kind;
    h[1] = port;
    h[2] = wire;
    h[4..8].copy_from_slice(&(len as u32).to_le_bytes());
    h[8..].copy_from_slice(&stamp.to_le_bytes());
    h
}

/// Writes a frame: header and bytes.
pub fn write_frame(
    w: &mut impl Write,
    port: Port,
    wire: Wire,
    timestamp_us: u64,
    bytes: &[u8],
) -> io::Result<()> {
    w.write_all(&header(
        FRAME,
        port as u8,
        wire as u8,
        bytes.len(),
        timestamp_us,
    ))?;
    w.write_all(bytes)
}

/// Writes any message but a frame's bytes (use [`write_frame`]).
pub fn write(w: &mut impl Write, m: &Message) -> io::Result<()> {
    let text = |kind: u8, s: &str| {
        let mut v = header(kind, 0, 0, s.len(), 0).to_vec();
        v.extend_from_slice(s.as_bytes());
        v
    };
    let bytes = match m {
        Message::Hello(spec) => text(HELLO, &spec.to_string()),
        Message::Frame { .. } => {
            return Err(io::Error::other("a frame is written with write_frame"))
        }
        Message::NoSignal { timestamp_us } => header(NO_SIGNAL, 0, 0, 0, *timestamp_us).to_vec(),
        Message::Mode(mode) => text(MODE, mode.name()),
        Message::Quit => header(QUIT, 0, 0, 0, 0).to_vec(),
        Message::Ready => header(READY, 0, 0, 0, 0).to_vec(),
        Message::Refused(why) => text(REFUSED, why),
        Message::State(s) => {
            let code = |w: Option<Wire>| w.map_or(0, |w| w as u8);
            let mut v = header(STATE, code(s.view), code(s.data), 16, 0).to_vec();
            v.extend_from_slice(&s.view_published.to_le_bytes());
            v.extend_from_slice(&s.data_published.to_le_bytes());
            v
        }
    };
    w.write_all(&bytes)
}

/// Reads the next message; a `Frame`'s bytes are left on the socket.
pub fn read(r: &mut impl Read) -> Result<Message, LinkError> {
    let mut h = [0u8; HEADER_BYTES];
    r.read_exact(&mut h)?;
    let len = u32::from_le_bytes([h[4], h[5], h[6], h[7]]);
    if len > MAX_PAYLOAD {
        return Err(LinkError::Bad(format!("payload of {len} bytes")));
    }
    let len = len as usize;
    let stamp = u64::from_le_bytes([h[8], h[9], h[10], h[11], h[12], h[13], h[14], h[15]]);
    let wire =
        |c: u8| Wire::from_code(c).ok_or_else(|| LinkError::Bad(format!("pixel format code {c}")));
    let mut text = || -> Result<String, LinkError> {
        if len > 4096 {
            return Err(LinkError::Bad(format!("{len}-byte text")));
        }
        let mut b = vec![0; len];
        r.read_exact(&mut b)?;
        String::from_utf8(b).map_err(|_| LinkError::Bad("text is not UTF-8".into()))
    };
    Ok(match h[0] {
        HELLO => Message::Hello(text()?.parse().map_err(LinkError::Bad)?),
        FRAME => Message::Frame {
            port: match h[1] {
                0 => Port::View,
                1 => Port::Data,
                p => return Err(LinkError::Bad(format!("port {p}"))),
            },
            wire: wire(h[2])?,
            timestamp_us: stamp,
            len,
        },
        NO_SIGNAL => Message::NoSignal {
            timestamp_us: stamp,
        },
        MODE => Message::Mode(
            text()?
                .parse()
                .map_err(|e| LinkError::Bad(format!("{e}")))?,
        ),
        QUIT => Message::Quit,
        READY => Message::Ready,
        REFUSED => Message::Refused(text()?),
        STATE => {
            if len != 16 {
                return Err(LinkError::Bad(format!("state of {len} bytes")));
            }
            let mut b = [0u8; 16];
            r.read_exact(&mut b)?;
            let code = |c: u8| if c == 0 { Ok(None) } else { wire(c).map(Some) };
            let n = |s: &[u8]| s.iter().rev().fold(0u64, |a, &b| a << 8 | u64::from(b));
            Message::State(State {
                view: code(h[1])?,
                data: code(h[2])?,
                view_published: n(&b[..8]),
                data_published: n(&b[8..]),
            })
        }
        k => return Err(LinkError::Bad(format!("message kind {k}"))),
    })
}

/// Reads a frame's `len` bytes into `bytes` (replacing its contents).
/// The buffer grows with the bytes that arrive, not with the `len` a
/// header claims: a peer that announces `MAX_PAYLOAD` and sends nothing
/// costs nothing (a reused buffer keeps its capacity, so a genuine
/// stream allocates once).
pub fn read_payload(r: &mut impl Read, len: usize, bytes: &mut Vec<u8>) -> io::Result<()> {
    bytes.clear();
    let got = r.take(len as u64).read_to_end(bytes)?;
    if got == len {
        Ok(())
    } else {
        Err(io::ErrorKind::UnexpectedEof.into())
    }
}

/// Reads and drops a frame's `len` bytes.
pub fn skip_payload(r: &mut impl Read, len: usize) -> io::Result<()> {
    let copied = io::copy(&mut r.take(len as u64), &mut io::sink())?;
    if copied == len as u64 {
        Ok(())
    } else {
        Err(io::ErrorKind::UnexpectedEof.into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> Spec {
        Spec {
            view_width: 640,
            view_height: 480,
            data_width: 320,
            data_height: 240,
            frame_rate_hz: 30,
            mode: ModeId::DepthEdge,
            camera: None,
        }
    }

    #[test]
    fn spec_text_round_trips_and_rejects_junk() {
        let s = spec();
        assert_eq!(s.to_string(), "640x480,320x240,30,depth-edge");
        assert_eq!(s.to_string().parse::<Spec>(), Ok(s.clone()));
        for bad in [
            "",
            "640x480,320x240,30",
            "0x480,320x240,30,raw",
            "640x480,320x240,0,raw",
            "640x480,320x240,30,nope",
            "640x480,320x240,30,raw,sim-1,extra",
            "99999x480,320x240,30,raw",
            "640x480,320x240,30,raw,",
            "640x480,320x240,30,raw,../x",
            "640x480,320x240,30,raw,a,b",
        ] {
            assert!(bad.parse::<Spec>().is_err(), "{bad:?} parsed");
        }
        let other = Spec {
            mode: ModeId::Raw,
            ..s.clone()
        };
        assert!(s.same_nodes(&other));
        assert!(!s.same_nodes(&Spec {
            frame_rate_hz: 60,
            ..s.clone()
        }));
        let one_of_two = Spec {
            camera: Some("sim-1".into()),
            ..s.clone()
        };
        assert_eq!(
            one_of_two.to_string(),
            "640x480,320x240,30,depth-edge,sim-1"
        );
        assert_eq!(
            one_of_two.to_string().parse::<Spec>(),
            Ok(one_of_two.clone())
        );
        assert!(!s.same_nodes(&one_of_two));
    }

    #[test]
    fn a_lone_camera_keeps_the_plain_names_and_one_of_several_its_serial() {
        let lone = Names { camera: None };
        assert_eq!(lone.socket(), SOCKET_NAME);
        assert_eq!(lone.lock(), LOCK_NAME);
        assert_eq!(lone.system_feed(), SYSTEM_FEED_NAME);
        assert_eq!(lone.view_node(), VIEW_NODE);
        assert_eq!(lone.data_node(), DATA_NODE);
        assert_eq!(lone.view_description("raw"), "SDI camera (raw)");
        let one = Names {
            camera: Some("sim-1"),
        };
        assert_eq!(one.socket(), "sdi-camera-sim-1.sock");
        assert_eq!(one.lock(), "sdi-camera-sim-1.lock");
        assert_eq!(one.system_feed(), "camera-feed-sim-1.sock");
        assert_eq!(one.view_node(), "sdi-camera-sim-1");
        assert_eq!(one.data_node(), "sdi-camera-data-sim-1");
        assert_eq!(one.view_description("raw"), "SDI camera sim-1 (raw)");
        assert_eq!(
            one.data_description("raw"),
            "SDI camera sim-1 raw data, Y16 DN+32768 (raw)"
        );
        for n in [
            VIEW_NODE,
            DATA_NODE,
            "sdi-camera-sim-1",
            "sdi-camera-data-A1",
        ] {
            assert!(is_camera_node(n), "{n}");
        }
        assert!(!is_camera_node("sdi-cameraX"));
        assert_eq!(system_feed_camera(SYSTEM_FEED_NAME), Some(None));
        assert_eq!(
            system_feed_camera(&one.system_feed()),
            Some(Some("sim-1".into()))
        );
        for other in [
            "camera-feed-.sock",
            "camera-feed-.x.sock",
            "camera-feedX.sock",
            "x.sock",
        ] {
            assert_eq!(system_feed_camera(other), None, "{other}");
        }
    }

    #[test]
    fn messages_round_trip() {
        let all = [
            Message::Hello(spec()),
            Message::NoSignal { timestamp_us: 42 },
            Message::Mode(ModeId::Separation),
            Message::Quit,
            Message::Ready,
            Message::Refused("busy".into()),
            Message::State(State {
                view: Some(Wire::Rgb),
                data: None,
                view_published: 7,
                data_published: u64::MAX,
            }),
        ];
        let mut buf = Vec::new();
        for m in &all {
            write(&mut buf, m).unwrap();
        }
        write_frame(&mut buf, Port::Data, Wire::Y16, 9, &[1, 2, 3]).unwrap();
        let mut r = &buf[..];
        for m in &all {
            assert_eq!(&read(&mut r).unwrap(), m);
        }
        let m = read(&mut r).unwrap();
        assert_eq!(
            m,
            Message::Frame {
                port: Port::Data,
                wire: Wire::Y16,
                timestamp_us: 9,
                len: 3
            }
        );
        let mut bytes = Vec::new();
        read_payload(&mut r, 3, &mut bytes).unwrap();
        assert_eq!(bytes, [1, 2, 3]);
        assert!(matches!(read(&mut r), Err(LinkError::Io(_))));
    }

    #[test]
    fn hostile_headers_are_typed_errors() {
        let mut h = header(FRAME, 9, 1, 10, 0).to_vec();
        assert!(matches!(read(&mut &h[..]), Err(LinkError::Bad(_))));
        h = header(FRAME, 0, 0, 10, 0).to_vec();
        assert!(matches!(read(&mut &h[..]), Err(LinkError::Bad(_))));
        h = header(99, 0, 0, 0, 0).to_vec();
        assert!(matches!(read(&mut &h[..]), Err(LinkError::Bad(_))));
        h = header(FRAME, 0, 1, 0, 0).to_vec();
        h[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(read(&mut &h[..]), Err(LinkError::Bad(_))));
        h = header(HELLO, 0, 0, 5000, 0).to_vec();
        assert!(matches!(read(&mut &h[..]), Err(LinkError::Bad(_))));
        h = header(STATE, 0, 0, 3, 0).to_vec();
        assert!(matches!(read(&mut &h[..]), Err(LinkError::Bad(_))));
        let mut short = &b"\x02\x00"[..];
        assert!(matches!(read(&mut short), Err(LinkError::Io(_))));
        let mut r = &[0u8; 4][..];
        assert!(skip_payload(&mut r, 8).is_err());
    }

    /// Found by fuzzing (camera_link): a frame header claiming the largest
    /// payload, then nothing, made the reader allocate and zero 64 MiB.
    #[test]
    fn a_short_payload_allocates_only_what_arrived() {
        let mut bytes = Vec::new();
        let err = read_payload(&mut &[7u8; 100][..], MAX_PAYLOAD as usize, &mut bytes)
            .expect_err("100 bytes of 64 MiB");
        assert_eq!(err.kind(), io::ErrorKind::UnexpectedEof);
        assert!(bytes.capacity() < 1 << 20, "capacity {}", bytes.capacity());
        // A whole payload reads, into the buffer's existing capacity.
        read_payload(&mut &[7u8; 100][..], 100, &mut bytes).expect("whole payload");
        assert_eq!(bytes, [7u8; 100]);
    }
}
