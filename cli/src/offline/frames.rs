//! Frame streams for the offline tools: `.npy` stacks (N x H x W or H x W,
//! DN, float32/float64/int16/uint16/int32, read one frame at a time) and
//! `.sdirec` recordings (raw frames, dark frame subtracted as recorded), plus a
//! `.npy` float32 writer whose leading dimension is fixed when it finishes
//! (recordings do not say up front how many frames they hold).

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

use sdi_core::sensor::SensorParams;
use sdi_core::{Frame, Image};
use sdi_recording::{format::is_recording_magic, Record, RecordingReader};

use crate::exit::CliError;

/// Largest frame accepted from any input, pixels.
pub const MAX_PIXELS: usize = 1 << 24;

fn runtime(path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("'{}': {e}", path.display()))
}

/// Element type of an input `.npy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dtype {
    F4,
    F8,
    I2,
    U2,
    I4,
}

impl Dtype {
    fn parse(descr: &str) -> Option<(Self, bool)> {
        let (order, t) = descr.split_at(1);
        let big = match order {
            "<" | "|" => false,
            ">" => true,
            _ => return None,
        };
        let d = match t {
            "f4" => Dtype::F4,
            "f8" => Dtype::F8,
            "i2" => Dtype::I2,
            "u2" => Dtype::U2,
            "i4" => Dtype::I4,
            _ => return None,
        };
        Some((d, big))
    }

    fn size(self) -> usize {
        match self {
            Dtype::I2 | Dtype::U2 => 2,
            Dtype::F4 | Dtype::I4 => 4,
            Dtype::F8 => 8,
        }
    }

    fn decode(self, big: bool, b: &[u8]) -> f32 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(b);
                if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }
            }};
        }
        match self {
            Dtype::F4 => get!(f32, 4),
            Dtype::F8 => get!(f64, 8) as f32,
            Dtype::I2 => f32::from(get!(i16, 2)),
            Dtype::U2 => f32::from(get!(u16, 2)),
            Dtype::I4 => get!(i32, 4) as f32,
        }
    }
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

/// Value text after `'key':` in a .npy header dict.
fn header_field<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header.find(&format!("'{key}'"))?;
    let rest = &header[at + key.len() + 2..];
    let rest = rest.trim_start().strip_prefix(':')?.trim_start();
    Some(rest)
}

fn parse_npy_header(header: &str) -> Result<(Dtype, bool, Vec<usize>), String> {
    let descr = header_field(header, "descr").ok_or("no 'descr'")?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|s| s.split('\'').next())
        .ok_or("bad 'descr'")?;
    let (dtype, big) = Dtype::parse(descr).ok_or_else(|| {
        format!("dtype '{descr}' is not supported (float32, float64, int16, uint16, int32)")
    })?;
    let fortran = header_field(header, "fortran_order").ok_or("no 'fortran_order'")?;
    if fortran.starts_with("True") {
        return Err("Fortran-ordered arrays are not supported".into());
    }
    let shape = header_field(header, "shape").ok_or("no 'shape'")?;
    let inner = shape
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or("bad 'shape'")?;
    let dims = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("bad dimension '{s}'"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((dtype, big, dims))
}

impl NpyFrames {
    /// Opens an N x H x W (or H x W: one frame) stack.
    pub fn open(path: &Path) -> Result<(Self, usize, usize), CliError> {
        let file = File::open(path).map_err(|e| runtime(path, e))?;
        let mut input = BufReader::new(file);
        let bad = |why: String| {
            CliError::Usage(format!("'{}': not a usable .npy: {why}", path.display()))
        };
        let mut magic = [0u8; 8];
        input
            .read_exact(&mut magic)
            .map_err(|_| bad("too short".into()))?;
        if &magic[..6] != b"\x93NUMPY" {
            return Err(bad("bad magic".into()));
        }
        let len = match magic[6] {
            1 => {
                let mut b = [0u8; 2];
                input
                    .read_exact(&mut b)
                    .map_err(|_| bad("truncated header".into()))?;
                usize::from(u16::from_le_bytes(b))
            }
            2 | 3 => {
                let mut b = [0u8; 4];
                input
                    .read_exact(&mut b)
                    .map_err(|_| bad("truncated header".into()))?;
                u32::from_le_bytes(b) as usize
            }
            v => return Err(bad(format!("version {v}"))),
        };
        if len > 1 << 16 {
            return Err(bad(format!("header of {len} bytes")));
        }
        let mut header = vec![0u8; len];
        input
            .read_exact(&mut header)
            .map_err(|_| bad("truncated header".into()))?;
        let header = String::from_utf8_lossy(&header);
        let (dtype, big_endian, shape) = parse_npy_header(&header).map_err(bad)?;
        let (n, h, w) = match shape[..] {
            [n, h, w] => (n, h, w),
            [h, w] => (1, h, w),
            _ => {
                return Err(bad(format!(
                    "shape {shape:?}; expected (frames, height, width) or (height, width)"
                )))
            }
        };
        if n == 0 || h == 0 || w == 0 {
            return Err(bad(format!("empty shape {shape:?}")));
        }
        if w.checked_mul(h).is_none_or(|p| p > MAX_PIXELS) {
            return Err(bad(format!(
                "frames of {w}x{h} are larger than 2^24 pixels"
            )));
        }
        // A truncated file is caught up front rather than after minutes of work.
        let data_start = 10 + if magic[6] == 1 { 0 } else { 2 } + len;
        let file_len = input
            .get_ref()
            .metadata()
            .map_err(|e| runtime(path, e))?
            .len();
        let want = (n as u64)
            .saturating_mul((w * h) as u64)
            .saturating_mul(dtype.size() as u64)
            .saturating_add(data_start as u64);
        if file_len < want {
            return Err(bad(format!(
                "truncated: {file_len} bytes, the header promises {want}"
            )));
        }
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
    Recording {
        reader: Box<RecordingReader<BufReader<File>>>,
        dark_dn: Option<Image<f32>>,
        warned_mode: Option<String>,
    },
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
            let input = FrameInput::Recording {
                reader: Box::new(reader),
                dark_dn: None,
                warned_mode: None,
            };
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
            FrameInput::Recording {
                reader,
                dark_dn,
                warned_mode,
            } => loop {
                match reader.next_record() {
                    None => {
                        if let Some(why) = reader.damaged_tail() {
                            eprintln!(
                                "warning: '{}' ends in a damaged record ({why}); the intact frames before it were used",
                                path.display()
                            );
                        }
                        return Ok(false);
                    }
                    Some(Record::Dark { dn, .. }) => *dark_dn = Some(dn),
                    Some(Record::End { .. }) => {}
                    Some(Record::Frame { mode, frame: f }) => {
                        if f.width() != frame.width() || f.height() != frame.height() {
                            return Err(runtime(
                                path,
                                format!(
                                    "frame {} is {}x{}, expected {}x{}",
                                    f.sequence,
                                    f.width(),
                                    f.height(),
                                    frame.width(),
                                    frame.height()
                                ),
                            ));
                        }
                        match warned_mode {
                            None => *warned_mode = Some(mode),
                            Some(m) if *m != mode => {
                                eprintln!("warning: the recording changes mode from {m} to {mode}; all frames are used");
                                *warned_mode = Some(mode);
                            }
                            Some(_) => {}
                        }
                        *frame = f;
                        if let Some(d) = dark_dn.as_ref().filter(|d| d.same_size(&frame.dn)) {
                            for (v, &k) in frame.dn.data.iter_mut().zip(&d.data) {
                                *v -= k;
                            }
                        }
                        return Ok(true);
                    }
                }
            },
        }
    }

    /// The mode the last frame read was recorded in (recordings only).
    pub fn last_mode(&self) -> Option<&str> {
        match self {
            FrameInput::Recording { warned_mode, .. } => warned_mode.as_deref(),
            FrameInput::Npy(_) => None,
        }
    }

    /// True for a recording that has supplied no dark frame so far.
    pub fn lacks_dark(&self) -> bool {
        matches!(self, FrameInput::Recording { dark_dn: None, .. })
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
