//! sdid's frames as numpy arrays: the `StreamFrames` wire format
//! (`sdi_api::frame_stream`, its one definition) read from our end of a
//! socket pair, each plane straight into the array that Python gets (the
//! one copy the socket costs), with the GIL released while waiting.

use std::io::{ErrorKind, Read};
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2};
use pyo3::prelude::*;
use sdi_api::frame_stream::{FrameHeader, WireError, HEADER_BYTES};

/// One mode output of sdid.
#[pyclass(module = "sdi", frozen, get_all)]
pub struct Frame {
    /// Signed difference, DN, float32 (height, width).
    pub dn: Py<PyArray2<f32>>,
    /// `PixelFlags` bits per pixel, uint8 (height, width).
    pub flags: Py<PyArray2<u8>>,
    /// sdid's sequence number of the frame that completed the output.
    pub sequence: u64,
    /// Capture timestamp, CLOCK_MONOTONIC microseconds.
    pub timestamp_us: u64,
    /// The mode's name.
    pub mode: String,
    pub width: u32,
    pub height: u32,
    /// Frames this stream skipped so far because the reader was slow.
    pub dropped: u64,
    /// The display range, |DN| at full scale; 0 = symmetric auto.
    pub max_abs_dn: f32,
    pub colormap: String,
    /// Separation mode: I+, electrons, float32 (height, width); else None.
    pub i_plus: Option<Py<PyArray2<f32>>>,
    /// Separation mode: I-, electrons; else None.
    pub i_minus: Option<Py<PyArray2<f32>>>,
    /// Separation mode: standard error of I+, electrons; else None.
    pub i_plus_se: Option<Py<PyArray2<f32>>>,
    /// Separation mode: standard error of I-, electrons; else None.
    pub i_minus_se: Option<Py<PyArray2<f32>>>,
}

#[pymethods]
impl Frame {
    fn __repr__(&self) -> String {
        format!(
            "<sdi.Frame {} {}x{} sequence {}{}>",
            self.mode,
            self.width,
            self.height,
            self.sequence,
            if self.i_plus.is_some() {
                " with I+, I-"
            } else {
                ""
            }
        )
    }
}

/// Why reading a frame stopped.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("no frame within the timeout")]
    Timeout,
    /// A signal arrived (Python handles it, then the read goes on).
    #[error("interrupted")]
    Interrupted,
    #[error("sdid closed the frame stream")]
    Closed,
    #[error("reading sdid's frames: {0}")]
    Io(#[from] std::io::Error),
    #[error("sdid's frame stream: {0}")]
    Wire(#[from] WireError),
}

/// A frame read from the wire, not yet handed to Python.
pub struct RawFrame {
    header: FrameHeader,
    dn: Vec<f32>,
    flags: Vec<u8>,
    /// I+, I-, their standard errors (separation mode).
    channels: Option<[Vec<f32>; 4]>,
}

impl RawFrame {
    /// The frame as Python sees it (no copy: each array owns its vector).
    pub fn into_py(self, py: Python<'_>) -> PyResult<Frame> {
        let (w, h) = (self.header.width as usize, self.header.height as usize);
        let f32s = |v: Vec<f32>| -> PyResult<Py<PyArray2<f32>>> {
            Ok(plane(v, w, h)?.into_pyarray(py).unbind())
        };
        let [i_plus, i_minus, i_plus_se, i_minus_se] = match self.channels {
            Some([a, b, c, d]) => [
                Some(f32s(a)?),
                Some(f32s(b)?),
                Some(f32s(c)?),
                Some(f32s(d)?),
            ],
            None => [None, None, None, None],
        };
        let header = self.header;
        Ok(Frame {
            dn: f32s(self.dn)?,
            flags: plane(self.flags, w, h)?.into_pyarray(py).unbind(),
            sequence: header.sequence,
            timestamp_us: header.timestamp_us,
            mode: header.mode,
            width: header.width,
            height: header.height,
            dropped: header.dropped,
            max_abs_dn: header.max_abs_dn,
            colormap: header.colormap,
            i_plus,
            i_minus,
            i_plus_se,
            i_minus_se,
        })
    }
}

/// `v` as a (h, w) array.
fn plane<T>(v: Vec<T>, w: usize, h: usize) -> PyResult<Array2<T>> {
    Array2::from_shape_vec((h, w), v)
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))
}

/// Our end of a `StreamFrames` socket. A read that times out keeps what it
/// got, so the next read goes on where it stopped.
pub struct FrameReader {
    socket: UnixStream,
    head: [u8; HEADER_BYTES],
    head_filled: usize,
    partial: Option<Partial>,
}

/// A frame whose body is being read: the planes and how far each is filled.
struct Partial {
    frame: RawFrame,
    /// Bytes of the body read so far.
    done: usize,
}

impl FrameReader {
    pub fn new(socket: UnixStream) -> Self {
        Self {
            socket,
            head: [0; HEADER_BYTES],
            head_filled: 0,
            partial: None,
        }
    }

    /// The next frame, if it comes before `deadline` (None: wait for ever).
    pub fn read(&mut self, deadline: Option<Instant>) -> Result<RawFrame, ReadError> {
        if self.partial.is_none() {
            while self.head_filled < HEADER_BYTES {
                let n = read_some(&self.socket, &mut self.head[self.head_filled..], deadline)?;
                self.head_filled += n;
            }
            self.head_filled = 0;
            let header = FrameHeader::decode(&self.head)?;
            let n = header.pixels();
            let channels = header
                .has_channels
                .then(|| std::array::from_fn(|_| vec![0f32; n]));
            self.partial = Some(Partial {
                frame: RawFrame {
                    header,
                    dn: vec![0f32; n],
                    flags: vec![0u8; n],
                    channels,
                },
                done: 0,
            });
        }
        let Some(p) = self.partial.as_mut() else {
            return Err(ReadError::Closed);
        };
        // The body's planes in wire order, read in place.
        loop {
            let mut offset = 0;
            let mut target: Option<&mut [u8]> = None;
            let f = &mut p.frame;
            let mut planes: Vec<&mut [u8]> =
                vec![bytemuck::cast_slice_mut(&mut f.dn), f.flags.as_mut_slice()];
            if let Some(ch) = f.channels.as_mut() {
                planes.extend(ch.iter_mut().map(|c| bytemuck::cast_slice_mut(c)));
            }
            for plane in planes {
                let len = plane.len();
                if p.done < offset + len {
                    target = Some(&mut plane[p.done - offset..]);
                    break;
                }
                offset += len;
            }
            let Some(buf) = target else { break };
            p.done += read_some(&self.socket, buf, deadline)?;
        }
        let mut frame = self
            .partial
            .take()
            .map(|p| p.frame)
            .ok_or(ReadError::Closed)?;
        from_le(&mut frame.dn);
        if let Some(ch) = frame.channels.as_mut() {
            ch.iter_mut().for_each(|c| from_le(c));
        }
        Ok(frame)
    }
}

/// Little-endian wire values to this machine's order (nothing on x86).
fn from_le(v: &mut [f32]) {
    if cfg!(target_endian = "big") {
        for x in v {
            *x = f32::from_bits(u32::from_le(x.to_bits()));
        }
    }
}

/// One read of at least one byte before `deadline`; a timeout, a signal or
/// the end of the stream is an error.
fn read_some(
    mut socket: &UnixStream,
    buf: &mut [u8],
    deadline: Option<Instant>,
) -> Result<usize, ReadError> {
    let wait = match deadline {
        // A zero duration means "block" to set_read_timeout: the least instead.
        Some(d) => Some(
            d.checked_duration_since(Instant::now())
                .ok_or(ReadError::Timeout)?
                .max(Duration::from_micros(1)),
        ),
        None => None,
    };
    socket.set_read_timeout(wait)?;
    match socket.read(buf) {
        Ok(0) => Err(ReadError::Closed),
        Ok(n) => Ok(n),
        Err(e) if e.kind() == ErrorKind::Interrupted => Err(ReadError::Interrupted),
        Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
            Err(ReadError::Timeout)
        }
        Err(e) => Err(e.into()),
    }
}
