//! The header of an input `.npy` stack (magic, version, header dict), read
//! before any frame: element type, byte order and N x H x W (or H x W: one
//! frame), each dimension checked.
//!
//! Separate from [`crate::npy`] (float32 only, the files sdid and sdictl
//! write) because sdictl accepts the integer and float64 stacks other tools
//! write; here, beside it and without I/O of its own, so the fuzz target
//! (`fuzz/fuzz_targets/npy_stack.rs`) runs the parser sdictl's offline
//! commands use (`cli/src/offline/frames.rs`) on the pure crates only.

use std::io::Read;

use crate::npy::{shape_tuple, ShapeError};

/// Largest frame accepted from any input, pixels: an `.npy` header's H x W
/// here, a recording's in sdictl's offline frame reader.
pub const MAX_PIXELS: usize = 1 << 24;

/// Longest header dict accepted, bytes (numpy writes well under 1 KiB).
pub const MAX_HEADER_BYTES: usize = 1 << 16;

/// Element type of an input `.npy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    F4,
    F8,
    I2,
    U2,
    I4,
}

impl Dtype {
    /// The type and whether it is big-endian, from a `descr` such as `<f4`.
    fn parse(descr: &str) -> Option<(Self, bool)> {
        let (order, t) = descr.split_at_checked(1)?;
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

    pub fn size(self) -> usize {
        match self {
            Dtype::I2 | Dtype::U2 => 2,
            Dtype::F4 | Dtype::I4 => 4,
            Dtype::F8 => 8,
        }
    }

    /// One element's value, DN.
    pub fn decode(self, big: bool, b: &[u8]) -> f32 {
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

/// What an input `.npy`'s header says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NpyHeader {
    pub dtype: Dtype,
    pub big_endian: bool,
    pub frames: usize,
    pub height: usize,
    pub width: usize,
    /// Offset of the first element, bytes.
    pub data_start: usize,
}

impl NpyHeader {
    /// Bytes the header promises: header and every frame.
    pub fn file_bytes(&self) -> u64 {
        (self.frames as u64)
            .saturating_mul((self.width * self.height) as u64)
            .saturating_mul(self.dtype.size() as u64)
            .saturating_add(self.data_start as u64)
    }
}

/// Why a file is not a usable `.npy` stack.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NpyHeaderError {
    #[error("too short")]
    TooShort,
    #[error("bad magic")]
    BadMagic,
    #[error("truncated header")]
    Truncated,
    #[error("version {0}")]
    Version(u8),
    #[error("header of {0} bytes")]
    HeaderTooLong(usize),
    #[error("no '{0}'")]
    MissingKey(&'static str),
    #[error("bad '{0}'")]
    BadValue(&'static str),
    #[error("dtype '{0}' is not supported (float32, float64, int16, uint16, int32)")]
    Dtype(String),
    #[error("Fortran-ordered arrays are not supported")]
    FortranOrder,
    #[error("bad dimension '{0}'")]
    BadDimension(String),
    #[error("shape {0:?}; expected (frames, height, width) or (height, width)")]
    Rank(Vec<usize>),
    #[error("empty shape {0:?}")]
    Empty(Vec<usize>),
    #[error("frames of {width}x{height} are larger than 2^24 pixels")]
    TooLarge { width: usize, height: usize },
}

/// Value text after `'key':` in a .npy header dict.
fn header_field<'a>(header: &'a str, key: &'static str) -> Result<&'a str, NpyHeaderError> {
    let missing = || NpyHeaderError::MissingKey(key);
    let at = header.find(&format!("'{key}'")).ok_or_else(missing)?;
    let rest = &header[at + key.len() + 2..];
    let rest = rest.trim_start().strip_prefix(':').ok_or_else(missing)?;
    Ok(rest.trim_start())
}

/// Element type, byte order and shape from the header dict.
fn parse_dict(header: &str) -> Result<(Dtype, bool, Vec<usize>), NpyHeaderError> {
    let descr = header_field(header, "descr")?
        .strip_prefix('\'')
        .and_then(|s| s.split('\'').next())
        .ok_or(NpyHeaderError::BadValue("descr"))?;
    let (dtype, big) = Dtype::parse(descr).ok_or_else(|| NpyHeaderError::Dtype(descr.into()))?;
    if header_field(header, "fortran_order")?.starts_with("True") {
        return Err(NpyHeaderError::FortranOrder);
    }
    let dims = shape_tuple(header_field(header, "shape")?).map_err(|e| match e {
        ShapeError::NotTuple => NpyHeaderError::BadValue("shape"),
        ShapeError::BadDimension(s) => NpyHeaderError::BadDimension(s),
    })?;
    Ok((dtype, big, dims))
}

/// Reads the header from the start of `input`, leaving it at the first element.
pub fn read(input: &mut impl Read) -> Result<NpyHeader, NpyHeaderError> {
    let mut magic = [0u8; 8];
    input
        .read_exact(&mut magic)
        .map_err(|_| NpyHeaderError::TooShort)?;
    if &magic[..6] != b"\x93NUMPY" {
        return Err(NpyHeaderError::BadMagic);
    }
    let (len, len_bytes) = match magic[6] {
        1 => {
            let mut b = [0u8; 2];
            input
                .read_exact(&mut b)
                .map_err(|_| NpyHeaderError::Truncated)?;
            (usize::from(u16::from_le_bytes(b)), 2)
        }
        2 | 3 => {
            let mut b = [0u8; 4];
            input
                .read_exact(&mut b)
                .map_err(|_| NpyHeaderError::Truncated)?;
            (u32::from_le_bytes(b) as usize, 4)
        }
        v => return Err(NpyHeaderError::Version(v)),
    };
    if len > MAX_HEADER_BYTES {
        return Err(NpyHeaderError::HeaderTooLong(len));
    }
    let mut header = vec![0u8; len];
    input
        .read_exact(&mut header)
        .map_err(|_| NpyHeaderError::Truncated)?;
    let (dtype, big_endian, shape) = parse_dict(&String::from_utf8_lossy(&header))?;
    let (frames, height, width) = match shape[..] {
        [n, h, w] => (n, h, w),
        [h, w] => (1, h, w),
        _ => return Err(NpyHeaderError::Rank(shape)),
    };
    if frames == 0 || height == 0 || width == 0 {
        return Err(NpyHeaderError::Empty(shape));
    }
    if width.checked_mul(height).is_none_or(|p| p > MAX_PIXELS) {
        return Err(NpyHeaderError::TooLarge { width, height });
    }
    Ok(NpyHeader {
        dtype,
        big_endian,
        frames,
        height,
        width,
        data_start: magic.len() + len_bytes + len,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(dict: &str) -> Vec<u8> {
        let mut v = b"\x93NUMPY\x01\x00".to_vec();
        v.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        v.extend_from_slice(dict.as_bytes());
        v
    }

    #[test]
    fn reads_a_stack_header() {
        let dict = "{'descr': '>i2', 'fortran_order': False, 'shape': (5, 3, 4), }";
        let h = read(&mut &npy(dict)[..]).unwrap();
        assert_eq!((h.dtype, h.big_endian), (Dtype::I2, true));
        assert_eq!((h.frames, h.height, h.width), (5, 3, 4));
        assert_eq!(h.data_start, 10 + dict.len());
        assert_eq!(h.file_bytes(), (10 + dict.len() + 5 * 12 * 2) as u64);
    }

    /// `descr` is cut after its first character: an empty one, or one
    /// starting with a multi-byte character, is a typed error, not a panic.
    #[test]
    fn empty_or_non_ascii_descr_is_an_error() {
        for descr in ["", "é", "€f4"] {
            let dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': (2, 2), }}");
            assert_eq!(
                read(&mut &npy(&dict)[..]),
                Err(NpyHeaderError::Dtype(descr.into()))
            );
        }
    }

    #[test]
    fn hostile_shapes_are_errors() {
        let with_shape = |s: &str| {
            npy(&format!(
                "{{'descr': '<f4', 'fortran_order': False, 'shape': {s}, }}"
            ))
        };
        assert!(matches!(
            read(&mut &with_shape("(0, 2)")[..]),
            Err(NpyHeaderError::Empty(_))
        ));
        assert!(matches!(
            read(&mut &with_shape("(1, 99999999999999999999)")[..]),
            Err(NpyHeaderError::BadDimension(_))
        ));
        assert!(matches!(
            read(&mut &with_shape("(4294967296, 4294967296)")[..]),
            Err(NpyHeaderError::TooLarge { .. })
        ));
        assert!(matches!(
            read(&mut &with_shape("(1, 2, 3, 4)")[..]),
            Err(NpyHeaderError::Rank(_))
        ));
        assert_eq!(read(&mut &b"\x93NUMPY"[..]), Err(NpyHeaderError::TooShort));
    }
}
