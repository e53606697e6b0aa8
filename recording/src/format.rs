//! The `.sdirec` recording format (documented in `docs/recording.md`).
//!
//! ```text
//! file    := magic u32:len json[len] u32:crc32(json)       magic: "SDIREC02" (v2) or "SDIREC01" (v1)
//! record  := "SDIR" u8:kind u32:len payload[len] u32:crc32(kind, len, payload)
//! kind 1  := frame v1:   u64 sequence, u64 timestamp_us, u8 mode_len, mode, u32 width,
//!                        u32 height, f32[w*h] dn, u8[w*h] flags
//! kind 2  := dark frame: u32 width, u32 height, u32 frames, f32[w*h] dn
//! kind 3  := end:        u64 frames written, u64 frames dropped
//! kind 4  := frame v2:   u64 sequence, u64 timestamp_us, u8 mode_len, mode, u32 width,
//!                        u32 height, u8 samples, u8 compression, body
//!            body (after decompression) := samples[w*h] ‖ u8[w*h] flags
//!            samples 0: f32 DN; 1: i16 DN; 2: i16 half-DN (dn * 2)
//!            compression 0: none; 1: zstd; i16 samples are stored as all low
//!            bytes, then all high bytes (compresses better)
//! ```
//! `flags` are the frame's per-pixel [`PixelFlags`](sdi_core::PixelFlags)
//! bits (a sensor sets SATURATED). All integers and floats little-endian. Records are appended and written
//! out whole, so a killed writer leaves at most one incomplete record at the
//! tail, which readers detect (length or CRC) and skip.

use sdi_core::sensor::SensorParams;
use sdi_core::{Frame, Image};
use serde::{Deserialize, Serialize};

/// Magic of the current version (2: integer frames, compressed).
pub const FILE_MAGIC: &[u8; 8] = b"SDIREC02";
/// Magic of version 1 (f32 frames), still read.
pub const FILE_MAGIC_V1: &[u8; 8] = b"SDIREC01";
pub const FORMAT_VERSION: u32 = 2;

/// True when a file starting with `magic` is a recording (any version).
pub fn is_recording_magic(magic: &[u8]) -> bool {
    magic == FILE_MAGIC || magic == FILE_MAGIC_V1
}
pub const RECORD_MAGIC: &[u8; 4] = b"SDIR";
pub const KIND_FRAME_V1: u8 = 1;
pub const KIND_DARK: u8 = 2;
pub const KIND_END: u8 = 3;
pub const KIND_FRAME: u8 = 4;
/// Longest JSON header accepted.
pub const MAX_HEADER_BYTES: u32 = 1 << 20;
/// Largest frame side and pixel count accepted (a hostile header must not
/// make a reader allocate gigabytes: 4096 x 4096 x 5 bytes is 80 MiB).
pub const MAX_SIDE_PX: usize = 4096;
pub const MAX_PIXELS: usize = 4096 * 4096;
/// Longest mode name stored with a frame.
pub const MAX_MODE_BYTES: usize = 255;
/// zstd level for frame bodies: the fastest level takes most of the size
/// gain (`cargo bench -p sdi-recording --bench frame_encoding` times it).
const ZSTD_LEVEL: i32 = 1;

const SAMPLES_F32: u8 = 0;
const SAMPLES_I16: u8 = 1;
const SAMPLES_I16_HALF: u8 = 2;
const COMPRESSION_NONE: u8 = 0;
const COMPRESSION_ZSTD: u8 = 1;

/// Metadata at the start of every recording.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub format_version: u32,
    /// Mode active when the recording started (each frame names its own).
    pub mode: String,
    pub backend: String,
    pub sensor: SensorParams,
    pub exposure_us: f64,
    pub frame_rate_hz: f64,
    pub modulation_hz: f64,
    /// Wall-clock start, seconds since the Unix epoch.
    pub started_unix_s: f64,
    pub calibration: Calibration,
}

/// Calibration in force when the recording started.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// Frames averaged into the dark frame (0: none; the dark frame itself is a kind-2 record).
    pub dark_frames: u32,
    /// Temporal variance of dark frames, DN^2 (read noise once per readout, eq. skellamvar).
    pub read_noise_variance_dn2: Option<f64>,
    pub fixed_pattern_sigma_dn: Option<f64>,
}

/// A header field outside its sane range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("recording header: {field} = {value} is out of range: expected {allowed}")]
pub struct HeaderError {
    pub field: &'static str,
    pub value: String,
    pub allowed: String,
}

fn bad(field: &'static str, value: impl ToString, allowed: impl ToString) -> HeaderError {
    HeaderError {
        field,
        value: value.to_string(),
        allowed: allowed.to_string(),
    }
}

fn finite_in(field: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), HeaderError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(bad(field, v, format!("[{lo}, {hi}]")))
    }
}

impl Header {
    /// A header of the current version for `sensor` as it is set up: the
    /// capture timing is the sensor's own, no calibration, started at the
    /// epoch (set `started_unix_s` for a real recording).
    pub fn for_sensor(mode: &str, backend: &str, sensor: SensorParams) -> Self {
        Self {
            format_version: FORMAT_VERSION,
            mode: mode.into(),
            backend: backend.into(),
            exposure_us: sensor.exposure_us,
            frame_rate_hz: sensor.frame_rate_hz,
            modulation_hz: sensor.modulation_hz,
            sensor,
            started_unix_s: 0.0,
            calibration: Calibration::default(),
        }
    }

    /// Rejects every field a player or converter could not use safely:
    /// sizes beyond [`MAX_SIDE_PX`]/[`MAX_PIXELS`], a frame rate outside
    /// [`sdi_core::sensor::capture_range::FRAME_RATE_HZ`], non-finite numbers, and
    /// sensor parameters [`SensorParams::validate`] refuses.
    pub fn validate(&self) -> Result<(), HeaderError> {
        if !(1..=FORMAT_VERSION).contains(&self.format_version) {
            return Err(bad(
                "format_version",
                self.format_version,
                format!("1..={FORMAT_VERSION}"),
            ));
        }
        let (w, h) = (self.sensor.width, self.sensor.height);
        if !(1..=MAX_SIDE_PX).contains(&w) {
            return Err(bad("sensor.width", w, format!("1..={MAX_SIDE_PX}")));
        }
        if !(1..=MAX_SIDE_PX).contains(&h) {
            return Err(bad("sensor.height", h, format!("1..={MAX_SIDE_PX}")));
        }
        if w * h > MAX_PIXELS {
            return Err(bad(
                "sensor.width*height",
                w * h,
                format!("<= {MAX_PIXELS}"),
            ));
        }
        self.sensor.validate().map_err(|e| HeaderError {
            field: "sensor",
            value: format!("{} = {}", e.name, e.value),
            allowed: e.allowed.into(),
        })?;
        let (lo, hi) = sdi_core::sensor::capture_range::FRAME_RATE_HZ.bounds();
        finite_in("frame_rate_hz", self.frame_rate_hz, lo, hi)?;
        finite_in("exposure_us", self.exposure_us, f64::MIN_POSITIVE, 1e6)?;
        finite_in("modulation_hz", self.modulation_hz, f64::MIN_POSITIVE, 1e12)?;
        finite_in("started_unix_s", self.started_unix_s, 0.0, 1e11)?;
        if let Some(v) = self.calibration.read_noise_variance_dn2 {
            finite_in("calibration.read_noise_variance_dn2", v, 0.0, f64::MAX)?;
        }
        if let Some(v) = self.calibration.fixed_pattern_sigma_dn {
            finite_in("calibration.fixed_pattern_sigma_dn", v, 0.0, f64::MAX)?;
        }
        for (field, s) in [("mode", &self.mode), ("backend", &self.backend)] {
            if s.len() > MAX_MODE_BYTES {
                return Err(bad(field, s.len(), format!("<= {MAX_MODE_BYTES} bytes")));
            }
        }
        Ok(())
    }

    /// Longest record payload a valid file of this frame size holds: an
    /// uncompressed f32 frame record (compressed bodies are stored only
    /// when smaller). Readers allocate at most this per record.
    pub fn max_payload_bytes(&self) -> usize {
        let px = self.sensor.width.saturating_mul(self.sensor.height);
        64 + MAX_MODE_BYTES + px.saturating_mul(5)
    }
}

/// One decoded record.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    Frame { mode: String, frame: Frame },
    Dark { frames: u32, dn: Image<f32> },
    End { frames: u64, dropped: u64 },
}

fn frame_prefix(mode: &str, frame: &Frame, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&frame.sequence.to_le_bytes());
    out.extend_from_slice(&frame.timestamp_us.to_le_bytes());
    let mode = truncate_utf8(mode, MAX_MODE_BYTES);
    out.push(mode.len() as u8);
    out.extend_from_slice(mode.as_bytes());
    out.extend_from_slice(&(frame.width() as u32).to_le_bytes());
    out.extend_from_slice(&(frame.height() as u32).to_le_bytes());
}

fn truncate_utf8(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

/// Encodes a version-1 frame record's payload (kind 1, f32 samples): kept
/// so tests can write the version-1 format and the bench can compare sizes.
pub fn encode_frame_v1(mode: &str, frame: &Frame, out: &mut Vec<u8>) {
    frame_prefix(mode, frame, out);
    for v in &frame.dn.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&frame.saturated.data);
}

/// The exact i16 for `v` at `scale`, when `v * scale` is one (bit for bit:
/// -0.0, NaN and fractions are not).
fn exact_i16(v: f32, scale: f32) -> Option<i16> {
    let s = v * scale;
    let i = s as i16;
    ((i as f32) / scale).to_bits().eq(&v.to_bits()).then_some(i)
}

/// Encodes a frame record's payload (kind 4): samples as i16 when every
/// value is an integer (or every value a half-integer: the board's
/// two-quad mean) that f32 gives back bit for bit, else f32; the body is
/// zstd-compressed when that is smaller. `scratch` is reused between calls.
pub fn encode_frame(mode: &str, frame: &Frame, out: &mut Vec<u8>, scratch: &mut Vec<u8>) {
    frame_prefix(mode, frame, out);
    let dn = &frame.dn.data;
    scratch.clear();
    let samples = [(SAMPLES_I16, 1.0f32), (SAMPLES_I16_HALF, 2.0)]
        .into_iter()
        .find(|&(_, scale)| dn.iter().all(|&v| exact_i16(v, scale).is_some()));
    let samples = match samples {
        Some((kind, scale)) => {
            // low bytes, then high bytes
            scratch.resize(dn.len() * 2, 0);
            let (lo, hi) = scratch.split_at_mut(dn.len());
            for ((v, l), h) in dn.iter().zip(lo).zip(hi) {
                let b = exact_i16(*v, scale).unwrap_or(0).to_le_bytes();
                *l = b[0];
                *h = b[1];
            }
            kind
        }
        None => {
            for v in dn {
                scratch.extend_from_slice(&v.to_le_bytes());
            }
            SAMPLES_F32
        }
    };
    scratch.extend_from_slice(&frame.saturated.data);
    out.push(samples);
    match zstd::bulk::compress(scratch, ZSTD_LEVEL) {
        Ok(z) if z.len() < scratch.len() => {
            out.push(COMPRESSION_ZSTD);
            out.extend_from_slice(&z);
        }
        _ => {
            out.push(COMPRESSION_NONE);
            out.extend_from_slice(scratch);
        }
    }
}

/// Encodes a dark-frame record's payload (kind 2).
pub fn encode_dark(frames: u32, dn: &Image<f32>, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&(dn.width as u32).to_le_bytes());
    out.extend_from_slice(&(dn.height as u32).to_le_bytes());
    out.extend_from_slice(&frames.to_le_bytes());
    for v in &dn.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Encodes an end record's payload (kind 3).
pub fn encode_end(frames: u64, dropped: u64, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&frames.to_le_bytes());
    out.extend_from_slice(&dropped.to_le_bytes());
}

/// CRC32 over kind, length and payload.
pub fn record_crc(kind: u8, payload: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&[kind]);
    h.update(&(payload.len() as u32).to_le_bytes());
    h.update(payload);
    h.finalize()
}

/// A whole record as written to the file: magic, kind, length, payload, CRC.
pub fn record_bytes(kind: u8, payload: &[u8], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(RECORD_MAGIC);
    out.push(kind);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&record_crc(kind, payload).to_le_bytes());
}

/// The file header: `magic` (normally [`FILE_MAGIC`]), length, JSON, CRC.
pub fn header_bytes(magic: &[u8; 8], header: &Header) -> serde_json::Result<Vec<u8>> {
    let json = serde_json::to_vec(header)?;
    let mut head = Vec::with_capacity(json.len() + 16);
    head.extend_from_slice(magic);
    head.extend_from_slice(&(json.len() as u32).to_le_bytes());
    head.extend_from_slice(&json);
    head.extend_from_slice(&crc32fast::hash(&json).to_le_bytes());
    Ok(head)
}

/// Why a payload could not be decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("malformed {what} record: {why}")]
pub struct DecodeError {
    pub what: &'static str,
    pub why: String,
}

struct Cursor<'a> {
    buf: &'a [u8],
    what: &'static str,
}

impl<'a> Cursor<'a> {
    fn err(&self, why: String) -> DecodeError {
        DecodeError {
            what: self.what,
            why,
        }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if self.buf.len() < n {
            return Err(self.err(format!("needs {n} more bytes, has {}", self.buf.len())));
        }
        let (a, b) = self.buf.split_at(n);
        self.buf = b;
        Ok(a)
    }
    fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32, DecodeError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Result<u64, DecodeError> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
    /// Width and height, which must be the recording's.
    fn size(&mut self, expect: (usize, usize)) -> Result<(usize, usize), DecodeError> {
        let (w, h) = (self.u32()? as usize, self.u32()? as usize);
        if (w, h) != expect {
            return Err(self.err(format!(
                "size {w}x{h} in a recording of {}x{}",
                expect.0, expect.1
            )));
        }
        Ok((w, h))
    }
    fn done(&self) -> Result<(), DecodeError> {
        if self.buf.is_empty() {
            Ok(())
        } else {
            Err(self.err(format!("{} trailing bytes", self.buf.len())))
        }
    }
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn frame(
    (w, h): (usize, usize),
    dn: Vec<f32>,
    flags: Vec<u8>,
    timestamp_us: u64,
    sequence: u64,
) -> Frame {
    Frame {
        dn: Image {
            width: w,
            height: h,
            data: dn,
        },
        saturated: Image {
            width: w,
            height: h,
            data: flags,
        },
        timestamp_us,
        sequence,
    }
}

/// Decodes a record payload of the given kind for a recording of frames
/// `size` (width, height) pixels; frames and dark frames of another size
/// are malformed. Allocates at most one frame (and, for a compressed one,
/// a zstd context and its body: a reader keeps a [`Decoder`] instead).
pub fn decode(kind: u8, payload: &[u8], size: (usize, usize)) -> Result<Record, DecodeError> {
    Decoder::default().decode(kind, payload, size)
}

/// Decodes record payloads like [`decode`], keeping its zstd context and
/// the decompressed body between calls, so a frame costs no context setup
/// and no body allocation.
#[derive(Default)]
pub struct Decoder {
    zstd: Option<zstd::bulk::Decompressor<'static>>,
    /// The last decompressed body; exactly one frame's body long.
    body: Vec<u8>,
}

impl Decoder {
    /// [`decode`], reusing this decoder's state.
    pub fn decode(
        &mut self,
        kind: u8,
        payload: &[u8],
        size: (usize, usize),
    ) -> Result<Record, DecodeError> {
        decode_with(self, kind, payload, size)
    }
}

fn decode_with(
    dec: &mut Decoder,
    kind: u8,
    payload: &[u8],
    size: (usize, usize),
) -> Result<Record, DecodeError> {
    let px = size.0.saturating_mul(size.1);
    match kind {
        KIND_FRAME_V1 | KIND_FRAME => {
            let mut c = Cursor {
                buf: payload,
                what: "frame",
            };
            let sequence = c.u64()?;
            let timestamp_us = c.u64()?;
            let mode_len = c.u8()? as usize;
            let mode = String::from_utf8_lossy(c.take(mode_len)?).into_owned();
            let wh = c.size(size)?;
            let (dn, flags) = if kind == KIND_FRAME_V1 {
                let dn = f32s(c.take(px * 4)?);
                (dn, c.take(px)?.to_vec())
            } else {
                let samples = c.u8()?;
                let compression = c.u8()?;
                let sample_bytes = match samples {
                    SAMPLES_F32 => 4,
                    SAMPLES_I16 | SAMPLES_I16_HALF => 2,
                    other => return Err(c.err(format!("unknown sample type {other}"))),
                };
                let body_len = px * (sample_bytes + 1);
                let rest = c.take(c.buf.len())?;
                let body: &[u8] = match compression {
                    COMPRESSION_NONE => rest,
                    COMPRESSION_ZSTD => {
                        let zstd = match &mut dec.zstd {
                            Some(z) => z,
                            None => dec.zstd.insert(
                                zstd::bulk::Decompressor::new()
                                    .map_err(|e| c.err(format!("zstd: {e}")))?,
                            ),
                        };
                        // the buffer is one frame's body: a hostile stream
                        // cannot inflate past it (zstd fails instead)
                        dec.body.resize(body_len, 0);
                        let n = zstd
                            .decompress_to_buffer(rest, dec.body.as_mut_slice())
                            .map_err(|e| c.err(format!("zstd: {e}")))?;
                        &dec.body[..n]
                    }
                    other => return Err(c.err(format!("unknown compression {other}"))),
                };
                if body.len() != body_len {
                    return Err(c.err(format!("body of {} bytes, expected {body_len}", body.len())));
                }
                let (s, flags) = body.split_at(px * sample_bytes);
                let dn = match samples {
                    SAMPLES_F32 => f32s(s),
                    _ => {
                        // i16 / 2 is exact in f32, so * 0.5 gives the bits / 2.0 did
                        let scale = if samples == SAMPLES_I16 { 1.0 } else { 0.5 };
                        let (lo, hi) = s.split_at(px);
                        lo.iter()
                            .zip(hi)
                            .map(|(&l, &h)| f32::from(i16::from_le_bytes([l, h])) * scale)
                            .collect()
                    }
                };
                (dn, flags.to_vec())
            };
            c.done()?;
            Ok(Record::Frame {
                mode,
                frame: frame(wh, dn, flags, timestamp_us, sequence),
            })
        }
        KIND_DARK => {
            let mut c = Cursor {
                buf: payload,
                what: "dark frame",
            };
            let (w, h) = c.size(size)?;
            let frames = c.u32()?;
            let data = f32s(c.take(px * 4)?);
            c.done()?;
            Ok(Record::Dark {
                frames,
                dn: Image {
                    width: w,
                    height: h,
                    data,
                },
            })
        }
        KIND_END => {
            let mut c = Cursor {
                buf: payload,
                what: "end",
            };
            let frames = c.u64()?;
            let dropped = c.u64()?;
            c.done()?;
            Ok(Record::End { frames, dropped })
        }
        other => Err(DecodeError {
            what: "unknown",
            why: format!("kind {other}"),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame_of(dn: Vec<f32>) -> Frame {
        let n = dn.len();
        let mut f = Frame::new(n, 1);
        f.dn.data = dn;
        f.saturated.data = (0..n).map(|i| (i % 3 == 0) as u8).collect();
        f.sequence = 7;
        f.timestamp_us = 123;
        f
    }

    fn round_trip(dn: Vec<f32>) -> (u8, Frame) {
        let f = frame_of(dn);
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        encode_frame("raw", &f, &mut out, &mut scratch);
        let prefix = 8 + 8 + 1 + 3 + 8;
        let samples = out[prefix];
        match decode(KIND_FRAME, &out, (f.width(), 1)) {
            Ok(Record::Frame { mode, frame }) => {
                assert_eq!(mode, "raw");
                (samples, frame)
            }
            other => panic!("{other:?}"),
        }
    }

    fn assert_bits_eq(a: &[f32], b: &[f32]) {
        let a: Vec<u32> = a.iter().map(|v| v.to_bits()).collect();
        let b: Vec<u32> = b.iter().map(|v| v.to_bits()).collect();
        assert_eq!(a, b);
    }

    /// A zstd frame record of `px` pixels whose body is `body`.
    fn zstd_record(px: usize, body: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        frame_prefix("raw", &frame_of(vec![0.0; px]), &mut out);
        out.extend_from_slice(&[SAMPLES_I16, COMPRESSION_ZSTD]);
        out.extend_from_slice(&zstd::bulk::compress(body, ZSTD_LEVEL).unwrap());
        out
    }

    #[test]
    fn a_zstd_body_of_another_length_is_malformed() {
        // one frame's body is 3 bytes a pixel; a bomb inflates far past it
        for len in [0, 3 * 100 - 1, 3 * 100 + 1, 1 << 20] {
            let rec = zstd_record(100, &vec![1u8; len]);
            let mut d = Decoder::default();
            for _ in 0..2 {
                let e = d.decode(KIND_FRAME, &rec, (100, 1)).unwrap_err();
                assert_eq!(e.what, "frame", "{len}");
                assert_eq!(decode(KIND_FRAME, &rec, (100, 1)).unwrap_err(), e);
            }
        }
    }

    #[test]
    fn one_decoder_decodes_every_record_as_a_fresh_one() {
        let frames = [
            (0..500).map(|i| (i % 97) as f32 - 40.0).collect::<Vec<_>>(),
            (0..500).map(|i| i as f32 * 0.5 - 70.0).collect(),
            (0..500).map(|i| i as f32 * 0.25).collect(),
            (0..500)
                .map(|i| ((i * 7919) % 65536) as f32 - 32768.0)
                .collect(),
        ];
        let mut d = Decoder::default();
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        for dn in frames.iter().chain(frames.iter().rev()) {
            encode_frame("raw", &frame_of(dn.clone()), &mut out, &mut scratch);
            let fresh = decode(KIND_FRAME, &out, (500, 1)).unwrap();
            let reused = d.decode(KIND_FRAME, &out, (500, 1)).unwrap();
            match (fresh, reused) {
                (Record::Frame { frame: a, .. }, Record::Frame { frame: b, .. }) => {
                    assert_bits_eq(&a.dn.data, dn);
                    assert_bits_eq(&b.dn.data, dn);
                    assert_eq!(a.saturated.data, b.saturated.data);
                }
                other => panic!("{other:?}"),
            }
            // a damaged record between frames leaves the decoder usable
            let bad = zstd_record(500, &[9u8; 7]);
            assert!(d.decode(KIND_FRAME, &bad, (500, 1)).is_err());
            assert!(d
                .decode(KIND_FRAME, &out[..out.len() - 3], (500, 1))
                .is_err());
        }
    }

    #[test]
    fn integral_frames_are_stored_as_i16_bit_exact() {
        let dn: Vec<f32> = (0..500)
            .map(|i| ((i * 37) % 8191) as f32 - 4095.0)
            .collect();
        let (samples, back) = round_trip(dn.clone());
        assert_eq!(samples, SAMPLES_I16);
        assert_bits_eq(&back.dn.data, &dn);
        assert_eq!(back.saturated.data, frame_of(dn).saturated.data);
        assert_eq!((back.sequence, back.timestamp_us), (7, 123));
    }

    #[test]
    fn half_integral_frames_are_stored_as_i16_half_dn() {
        let dn: Vec<f32> = (0..300).map(|i| i as f32 * 0.5 - 70.0).collect();
        let (samples, back) = round_trip(dn.clone());
        assert_eq!(samples, SAMPLES_I16_HALF);
        assert_bits_eq(&back.dn.data, &dn);
    }

    #[test]
    fn other_frames_keep_f32_bit_exact() {
        for odd in [0.25f32, -0.0, f32::NAN, f32::INFINITY, 40000.0, 1e-30] {
            let mut dn: Vec<f32> = (0..64).map(|i| i as f32).collect();
            dn[5] = odd;
            let (samples, back) = round_trip(dn.clone());
            assert_eq!(samples, SAMPLES_F32, "{odd}");
            assert_bits_eq(&back.dn.data, &dn);
        }
    }

    #[test]
    fn v1_frames_still_decode() {
        let f = frame_of(vec![1.5, -2.0, 3.25]);
        let mut out = Vec::new();
        encode_frame_v1("snapshot", &f, &mut out);
        match decode(KIND_FRAME_V1, &out, (3, 1)) {
            Ok(Record::Frame { mode, frame }) => {
                assert_eq!(mode, "snapshot");
                assert_eq!(frame, f);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_frame_of_another_size_is_malformed() {
        let f = frame_of(vec![1.0; 6]);
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        encode_frame("raw", &f, &mut out, &mut scratch);
        assert!(decode(KIND_FRAME, &out, (3, 2)).is_err());
        assert!(decode(KIND_FRAME, &out, (6, 1)).is_ok());
    }

    #[test]
    fn long_mode_names_are_cut_at_a_char_boundary() {
        let name = "é".repeat(200);
        let f = frame_of(vec![0.0; 2]);
        let (mut out, mut scratch) = (Vec::new(), Vec::new());
        encode_frame(&name, &f, &mut out, &mut scratch);
        let Ok(Record::Frame { mode, .. }) = decode(KIND_FRAME, &out, (2, 1)) else {
            panic!()
        };
        assert_eq!(mode.len(), 254);
        assert!(name.starts_with(&mode));
    }
}
