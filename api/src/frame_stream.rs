//! The wire format of `StreamFrames`: each mode output sdid writes into the
//! descriptor a client passed, one definition for sdid (encoder) and
//! `sdictl view` (decoder).
//!
//! A frame is a fixed [`HEADER_BYTES`]-byte header, then the body: the
//! signed DN (`f32`, row-major), the per-pixel flags (`u8`, `PixelFlags`
//! bits), and in the separation mode I+, I- and their standard errors
//! (`f32`, electrons, in that order). All
//! numbers are little-endian. The header carries the display map sdid
//! renders the frame with, so a client renders it exactly as sdid does.

/// Bytes of a frame header.
pub const HEADER_BYTES: usize = 96;
/// First four bytes of every frame.
pub const MAGIC: [u8; 4] = *b"SDIF";
/// Version of this layout.
pub const VERSION: u16 = 1;
/// Largest frame a reader accepts, pixels: bounds what a header can make a
/// client allocate.
pub const MAX_PIXELS: usize = 4096 * 4096;

const MODE_FIELD: usize = 32;
const COLORMAP_FIELD: usize = 16;
const FLAG_CHANNELS: u16 = 1;

/// What precedes each frame's pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameHeader {
    /// sdid's sequence number of the frame that completed the output.
    pub sequence: u64,
    /// Capture timestamp, CLOCK_MONOTONIC microseconds.
    pub timestamp_us: u64,
    pub width: u32,
    pub height: u32,
    /// The display range, |DN| at full scale; 0 = symmetric auto.
    pub max_abs_dn: f32,
    /// Frames this stream skipped so far because the reader was slow.
    pub dropped: u64,
    /// The mode's name (`ModeId`'s).
    pub mode: String,
    /// The colormap's name (`Colormap`'s).
    pub colormap: String,
    /// Whether I+, I- and their standard errors follow the flags (separation mode).
    pub has_channels: bool,
}

/// A header a reader refuses.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("not a frame header (magic {0:02x?})")]
    Magic([u8; 4]),
    #[error("frame stream version {0}, this reader knows {VERSION}")]
    Version(u16),
    #[error("frame of {width}x{height} pixels is larger than {MAX_PIXELS}")]
    TooLarge { width: u32, height: u32 },
    #[error("a name in the header is not UTF-8 or too long")]
    Name,
}

impl FrameHeader {
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Bytes of the body following this header.
    pub fn body_bytes(&self) -> usize {
        let planes_f32 = if self.has_channels { 5 } else { 1 };
        self.pixels() * (4 * planes_f32 + 1)
    }

    /// The header's bytes. Names longer than their field are refused.
    pub fn encode(&self) -> Result<[u8; HEADER_BYTES], WireError> {
        let mut b = [0u8; HEADER_BYTES];
        b[0..4].copy_from_slice(&MAGIC);
        b[4..6].copy_from_slice(&VERSION.to_le_bytes());
        let flags = if self.has_channels { FLAG_CHANNELS } else { 0 };
        b[6..8].copy_from_slice(&flags.to_le_bytes());
        b[8..16].copy_from_slice(&self.sequence.to_le_bytes());
        b[16..24].copy_from_slice(&self.timestamp_us.to_le_bytes());
        b[24..28].copy_from_slice(&self.width.to_le_bytes());
        b[28..32].copy_from_slice(&self.height.to_le_bytes());
        b[32..36].copy_from_slice(&self.max_abs_dn.to_le_bytes());
        b[40..48].copy_from_slice(&self.dropped.to_le_bytes());
        put_name(&mut b[48..48 + MODE_FIELD], &self.mode)?;
        put_name(&mut b[80..80 + COLORMAP_FIELD], &self.colormap)?;
        Ok(b)
    }

    /// Reads a header, refusing what is not one or would be too large.
    pub fn decode(b: &[u8; HEADER_BYTES]) -> Result<Self, WireError> {
        let magic = [b[0], b[1], b[2], b[3]];
        if magic != MAGIC {
            return Err(WireError::Magic(magic));
        }
        let version = u16::from_le_bytes([b[4], b[5]]);
        if version != VERSION {
            return Err(WireError::Version(version));
        }
        let u32_at = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        let u64_at = |i: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&b[i..i + 8]);
            u64::from_le_bytes(a)
        };
        let flags = u16::from_le_bytes([b[6], b[7]]);
        let (width, height) = (u32_at(24), u32_at(28));
        if width as usize * height as usize > MAX_PIXELS {
            return Err(WireError::TooLarge { width, height });
        }
        Ok(Self {
            sequence: u64_at(8),
            timestamp_us: u64_at(16),
            width,
            height,
            max_abs_dn: f32::from_bits(u32_at(32)),
            dropped: u64_at(40),
            mode: get_name(&b[48..48 + MODE_FIELD])?,
            colormap: get_name(&b[80..80 + COLORMAP_FIELD])?,
            has_channels: flags & FLAG_CHANNELS != 0,
        })
    }
}

fn put_name(field: &mut [u8], name: &str) -> Result<(), WireError> {
    let bytes = name.as_bytes();
    if bytes.len() > field.len() {
        return Err(WireError::Name);
    }
    field[..bytes.len()].copy_from_slice(bytes);
    Ok(())
}

fn get_name(field: &[u8]) -> Result<String, WireError> {
    let end = field.iter().position(|&c| c == 0).unwrap_or(field.len());
    std::str::from_utf8(&field[..end])
        .map(str::to_owned)
        .map_err(|_| WireError::Name)
}

/// Appends `values` to `out` as little-endian `f32`s.
pub fn put_f32s(out: &mut Vec<u8>, values: &[f32]) {
    out.reserve(values.len() * 4);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Reads `out.len()` little-endian `f32`s from `bytes` (which holds at least that many).
pub fn get_f32s(bytes: &[u8], out: &mut [f32]) {
    for (v, c) in out.iter_mut().zip(bytes.chunks_exact(4)) {
        *v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> FrameHeader {
        FrameHeader {
            sequence: 42,
            timestamp_us: 1_234_567,
            width: 320,
            height: 240,
            max_abs_dn: 0.0,
            dropped: 3,
            mode: "separation".into(),
            colormap: "diverging".into(),
            has_channels: true,
        }
    }

    #[test]
    fn header_round_trips() {
        let h = header();
        let back = FrameHeader::decode(&h.encode().unwrap()).unwrap();
        assert_eq!(back, h);
        assert_eq!(back.body_bytes(), 320 * 240 * 21);
    }

    #[test]
    fn hostile_headers_are_refused() {
        let mut b = header().encode().unwrap();
        b[0] = b'X';
        assert!(matches!(FrameHeader::decode(&b), Err(WireError::Magic(_))));
        let mut b = header().encode().unwrap();
        b[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            FrameHeader::decode(&b),
            Err(WireError::TooLarge { .. })
        ));
        let mut b = header().encode().unwrap();
        b[48] = 0xff;
        assert_eq!(FrameHeader::decode(&b), Err(WireError::Name));
        let long = FrameHeader {
            mode: "m".repeat(33),
            ..header()
        };
        assert_eq!(long.encode(), Err(WireError::Name));
    }

    #[test]
    fn f32s_round_trip() {
        let v = [1.5f32, -2.25, f32::INFINITY];
        let mut bytes = Vec::new();
        put_f32s(&mut bytes, &v);
        let mut back = [0f32; 3];
        get_f32s(&bytes, &mut back);
        assert_eq!(back, v);
    }
}
