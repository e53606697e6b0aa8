//! Frame streams for the offline tools: `.npy` stacks (N x H x W or H x W,
//! DN, float32/float64/int16/uint16/int32, read one frame at a time) and
//! `.sdirec` recordings (raw frames, dark frame subtracted as recorded), plus a
//! `.npy` float32 writer whose leading dimension is fixed when it finishes
//! (recordings do not say up front how many frames they hold).

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

use sdi_core::npy_header::{self, Dtype, NpyHeader, MAX_PIXELS};
use sdi_core::sensor::SensorParams;
use sdi_core::Frame;
use sdi_recording::{format::is_recording_magic, RecordedFrames, RecordingReader};

use crate::exit::CliError;

fn runtime(path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("'{}': {e}", path.display()))
}

/// An `.npy` stack read frame by frame.
pub struct NpyFrames {
    input: BufReader<File>,
    dtype: Dtype,
    big_endian: bool,
    frames: usize,
    read: usize,
    buf: Vec<u8>,
}

impl NpyFrames {
    /// Opens an N x H x W (or H x W: one frame) stack.
    pub fn open(path: &Path) -> Result<(Self, usize, usize), CliError> {
        let file = File::open(path).map_err(|e| runtime(path, e))?;
        let mut input = BufReader::new(file);
        let bad = |why: String| {
            CliError::Usage(format!("'{}': not a usable .npy: {why}", path.display()))
        };
        let header = npy_header::read(&mut input).map_err(|e| bad(e.to_string()))?;
        // A truncated file is caught up front rather than after minutes of work.
        let file_len = input
            .get_ref()
            .metadata()
            .map_err(|e| runtime(path, e))?
            .len();
        let want = header.file_bytes();
        if file_len < want {
            return Err(bad(format!(
                "truncated: {file_len} bytes, the header promises {want}"
            )));
        }
        let NpyHeader {
            dtype,
            big_endian,
            frames: n,
            height: h,
            width: w,
            ..
        } = header;
        let buf = vec![0u8; w * h * dtype.size()];
        Ok((
            Self {
                input,
                dtype,
                big_endian,
                frames: n,
                read: 0,
                buf,
            },
            w,
            h,
        ))
    }
}

/// Frames from a file: `.sdirec` recordings or `.npy` stacks.
pub enum FrameInput {
    Npy(NpyFrames),
    Recording(Box<RecordedFrames<BufReader<File>>>),
}

/// What an input says about itself.
#[derive(Debug, Clone)]
pub struct InputInfo {
    pub width: usize,
    pub height: usize,
    /// Sensor parameters stored with a recording.
    pub sensor: Option<SensorParams>,
    /// Temporal dark variance measured by sdid when the recording started, DN^2.
    pub read_variance_dn2: Option<f64>,
}

impl FrameInput {
    /// Opens a recording (`.sdirec`, or any file starting with its magic) or an `.npy`.
    pub fn open(path: &Path) -> Result<(Self, InputInfo), CliError> {
        let mut magic = [0u8; 8];
        let n = File::open(path)
            .and_then(|mut f| f.read(&mut magic))
            .map_err(|e| runtime(path, e))?;
        if n == 8 && is_recording_magic(&magic) {
            let reader = RecordingReader::open(path)
                .map_err(|e| CliError::Usage(format!("'{}': {e}", path.display())))?;
            let header = reader.header().clone();
            let input = FrameInput::Recording(Box::new(RecordedFrames::new(reader)));
            // Size from the first frame; the header's sensor gives it too.
            let info = InputInfo {
                width: header.sensor.width,
                height: header.sensor.height,
                sensor: Some(header.sensor.clone()),
                read_variance_dn2: header.calibration.read_noise_variance_dn2,
            };
            if info
                .width
                .checked_mul(info.height)
                .is_none_or(|p| p == 0 || p > MAX_PIXELS)
            {
                return Err(CliError::Usage(format!(
                    "'{}': recording of {}x{} pixels",
                    path.display(),
                    info.width,
                    info.height
                )));
            }
            Ok((input, info))
        } else {
            let (npy, w, h) = NpyFrames::open(path)?;
            Ok((
                FrameInput::Npy(npy),
                InputInfo {
                    width: w,
                    height: h,
                    sensor: None,
                    read_variance_dn2: None,
                },
            ))
        }
    }

    /// Reads the next frame into `frame` (resized as needed). `Ok(false)` at
    /// the end. Recordings: the latest dark frame is subtracted; frames of
    /// another size than the first are an error.
    pub fn next_frame(&mut self, path: &Path, frame: &mut Frame) -> Result<bool, CliError> {
        match self {
            FrameInput::Npy(n) => {
                if n.read >= n.frames {
                    return Ok(false);
                }
                n.input
                    .read_exact(&mut n.buf)
                    .map_err(|e| runtime(path, format!("frame {} of {}: {e}", n.read, n.frames)))?;
                let sz = n.dtype.size();
                for (v, b) in frame.dn.data.iter_mut().zip(n.buf.chunks_exact(sz)) {
                    *v = n.dtype.decode(n.big_endian, b);
                }
                frame.saturated.data.fill(0);
                frame.sequence = n.read as u64;
                n.read += 1;
                Ok(true)
            }
            FrameInput::Recording(frames) => match frames.next_frame() {
                Err(e) => Err(runtime(path, e)),
                Ok(None) => {
                    if let Some(why) = frames.damaged_tail() {
                        eprintln!(
                            "warning: '{}' ends in a damaged record ({why}); the intact frames before it were used",
                            path.display()
                        );
                    }
                    Ok(false)
                }
                Ok(Some(f)) => {
                    if let Some(m) = f.mode_changed_from {
                        eprintln!(
                            "warning: the recording changes mode from {m} to {}; all frames are used",
                            f.mode
                        );
                    }
                    *frame = f.frame;
                    Ok(true)
                }
            },
        }
    }

    /// The mode the last frame read was recorded in (recordings only).
    pub fn last_mode(&self) -> Option<&str> {
        match self {
            FrameInput::Recording(frames) => frames.last_mode(),
            FrameInput::Npy(_) => None,
        }
    }

    /// True for a recording that has supplied no dark frame so far.
    pub fn lacks_dark(&self) -> bool {
        matches!(self, FrameInput::Recording(f) if f.lacks_dark())
    }
}

/// A float32 `.npy` writer whose first dimension is written when it finishes.
pub struct NpyOut {
    w: BufWriter<File>,
    tail: Vec<usize>,
    count: usize,
    elems: usize,
}

/// Fixed header length so the shape can be rewritten in place.
const OUT_HEADER_BYTES: usize = 128;

fn out_header(shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut h = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    let pad = OUT_HEADER_BYTES.saturating_sub(10 + h.len() + 1);
    h.push_str(&" ".repeat(pad));
    h.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(h.len() as u16).to_le_bytes());
    out.extend_from_slice(h.as_bytes());
    out
}

impl NpyOut {
    /// `tail`: the shape after the leading dimension; `leading`: whether the
    /// array has a leading (counted) dimension at all.
    pub fn new(w: BufWriter<File>, tail: &[usize]) -> std::io::Result<Self> {
        let mut s = Self {
            w,
            tail: tail.to_vec(),
            count: 0,
            elems: tail.iter().product(),
        };
        let mut shape = vec![0];
        shape.extend_from_slice(tail);
        s.w.write_all(&out_header(&shape))?;
        Ok(s)
    }

    /// Appends one item of the tail shape.
    pub fn push(&mut self, data: &[f32]) -> std::io::Result<()> {
        if data.len() != self.elems {
            return Err(std::io::Error::other(format!(
                "{} values for an item of {}",
                data.len(),
                self.elems
            )));
        }
        for v in data {
            self.w.write_all(&v.to_le_bytes())?;
        }
        self.count += 1;
        Ok(())
    }

    pub fn count(&self) -> usize {
        self.count
    }

    /// Rewrites the header with the final count; `drop_leading` writes the
    /// tail shape alone (valid only when exactly one item was pushed).
    pub fn finish(mut self, drop_leading: bool) -> std::io::Result<()> {
        let mut shape = Vec::new();
        if !(drop_leading && self.count == 1) {
            shape.push(self.count);
        }
        shape.extend_from_slice(&self.tail);
        let header = out_header(&shape);
        if header.len() != OUT_HEADER_BYTES {
            return Err(std::io::Error::other("shape too long for the header"));
        }
        self.w.flush()?;
        let f = self.w.get_mut();
        f.seek(SeekFrom::Start(0))?;
        f.write_all(&header)?;
        f.flush()?;
        f.sync_all().or(Ok(()))
    }
}
