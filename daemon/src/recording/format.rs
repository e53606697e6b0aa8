//! The `.sdirec` recording format (documented in `docs/recording.md`).
//!
//! ```text
//! file    := header record*
//! header  := "SDIREC01" u32:len json[len] u32:crc32(json)
//! record  := "SDIR" u8:kind u32:len payload[len] u32:crc32(kind, len, payload)
//! kind 1  := frame:      u64 sequence, u64 timestamp_us, u8 mode_len, mode, u32 width,
//!                        u32 height, f32[w*h] dn, u8[w*h] saturated
//! kind 2  := dark frame: u32 width, u32 height, u32 frames, f32[w*h] dn
//! kind 3  := end:        u64 frames written, u64 frames dropped
//! ```
//! All integers and floats little-endian. Records are appended and written
//! out whole, so a killed writer leaves at most one incomplete record at the
//! tail, which readers detect (length or CRC) and skip.

use sdi_core::sensor::SensorParams;
use sdi_core::{Frame, Image};
use serde::{Deserialize, Serialize};

pub const FILE_MAGIC: &[u8; 8] = b"SDIREC01";
pub const RECORD_MAGIC: &[u8; 4] = b"SDIR";
pub const KIND_FRAME: u8 = 1;
pub const KIND_DARK: u8 = 2;
pub const KIND_END: u8 = 3;
/// Refuse records larger than this (a corrupt length must not allocate gigabytes).
pub const MAX_RECORD_BYTES: u32 = 256 << 20;

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

/// One decoded record.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    Frame { mode: String, frame: Frame },
    Dark { frames: u32, dn: Image<f32> },
    End { frames: u64, dropped: u64 },
}

/// Encodes a frame record's payload (kind 1).
pub fn encode_frame(mode: &str, frame: &Frame, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&frame.sequence.to_le_bytes());
    out.extend_from_slice(&frame.timestamp_us.to_le_bytes());
    let mode = &mode.as_bytes()[..mode.len().min(255)];
    out.push(mode.len() as u8);
    out.extend_from_slice(mode);
    out.extend_from_slice(&(frame.width() as u32).to_le_bytes());
    out.extend_from_slice(&(frame.height() as u32).to_le_bytes());
    for v in &frame.dn.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&frame.saturated.data);
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
    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if self.buf.len() < n {
            return Err(DecodeError {
                what: self.what,
                why: format!("needs {n} more bytes, has {}", self.buf.len()),
            });
        }
        let (a, b) = self.buf.split_at(n);
        self.buf = b;
        Ok(a)
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
    fn size(&mut self) -> Result<(usize, usize), DecodeError> {
        let (w, h) = (self.u32()? as usize, self.u32()? as usize);
        if w == 0 || h == 0 || w.saturating_mul(h) > (MAX_RECORD_BYTES as usize) / 5 {
            return Err(DecodeError {
                what: self.what,
                why: format!("bad size {w}x{h}"),
            });
        }
        Ok((w, h))
    }
    fn f32s(&mut self, n: usize) -> Result<Vec<f32>, DecodeError> {
        let b = self.take(n * 4)?;
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }
    fn done(&self) -> Result<(), DecodeError> {
        if self.buf.is_empty() {
            Ok(())
        } else {
            Err(DecodeError {
                what: self.what,
                why: format!("{} trailing bytes", self.buf.len()),
            })
        }
    }
}

/// Decodes a record payload of the given kind.
pub fn decode(kind: u8, payload: &[u8]) -> Result<Record, DecodeError> {
    match kind {
        KIND_FRAME => {
            let mut c = Cursor {
                buf: payload,
                what: "frame",
            };
            let sequence = c.u64()?;
            let timestamp_us = c.u64()?;
            let mode_len = c.take(1)?[0] as usize;
            let mode = String::from_utf8_lossy(c.take(mode_len)?).into_owned();
            let (w, h) = c.size()?;
            let dn = c.f32s(w * h)?;
            let saturated = c.take(w * h)?.to_vec();
            c.done()?;
            Ok(Record::Frame {
                mode,
                frame: Frame {
                    dn: Image {
                        width: w,
                        height: h,
                        data: dn,
                    },
                    saturated: Image {
                        width: w,
                        height: h,
                        data: saturated,
                    },
                    timestamp_us,
                    sequence,
                },
            })
        }
        KIND_DARK => {
            let mut c = Cursor {
                buf: payload,
                what: "dark frame",
            };
            let (w, h) = c.size()?;
            let frames = c.u32()?;
            let data = c.f32s(w * h)?;
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
