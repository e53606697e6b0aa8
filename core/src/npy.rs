//! NumPy `.npy` files of little-endian float32 (format versions 1.0 to 3.0).
//!
//! The writer streams: header first, then frames, so long recordings never sit
//! in memory. The reader rejects anything malformed with a typed error and
//! never trusts the header for allocation sizes.
//!
//! Hand-written because both crates that do this panic on hostile headers
//! (npyz 0.8 on a shape whose product overflows, ndarray-npy 0.9 on
//! `(0, 2^64-1)`; tests below); numpy checks it in `tests/tests/integration/npy_numpy.rs`.

use std::io::{Read, Write};

const MAGIC: &[u8; 6] = b"\x93NUMPY";
/// Largest header we accept when reading (numpy itself writes < 100 bytes).
const MAX_HEADER_BYTES: usize = 1 << 16;

/// Why a file is not a float32 `.npy` we can read.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("not a .npy file (bad magic)")]
    BadMagic,
    #[error("unsupported .npy version {0}.{1}")]
    UnsupportedVersion(u8, u8),
    #[error("malformed .npy header: {0}")]
    BadHeader(String),
    #[error("unsupported dtype {0}; expected '<f4'")]
    UnsupportedDtype(String),
    #[error("Fortran-ordered arrays are not supported")]
    FortranOrder,
    #[error("shape {0:?} is too large")]
    ShapeTooLarge(Vec<usize>),
    #[error("truncated data: expected {expected_bytes} bytes, found {found_bytes}")]
    Truncated {
        expected_bytes: u64,
        found_bytes: u64,
    },
    #[error("data does not match the shape: {0} elements given for shape {1:?}")]
    ShapeMismatch(usize, Vec<usize>),
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
}

fn header_text(shape: &[usize]) -> String {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut h = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    // magic(6) + version(2) + len(2) + header + '\n' is a multiple of 64.
    let total = 10 + h.len() + 1;
    h.push_str(&" ".repeat((64 - total % 64) % 64));
    h.push('\n');
    h
}

/// A `.npy` writer that takes the data in pieces (e.g. one frame at a time).
pub struct NpyF32Writer<W: Write> {
    w: W,
    shape: Vec<usize>,
    remaining: usize,
}

impl<W: Write> NpyF32Writer<W> {
    /// Writes the header for `shape`.
    pub fn new(mut w: W, shape: &[usize]) -> std::io::Result<Self> {
        let total = shape
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .ok_or_else(|| {
                std::io::Error::new(std::io::ErrorKind::InvalidInput, "shape overflows")
            })?;
        let header = header_text(shape);
        let len = u16::try_from(header.len()).map_err(|_| {
            std::io::Error::new(std::io::ErrorKind::InvalidInput, "header too long")
        })?;
        w.write_all(MAGIC)?;
        w.write_all(&[1, 0])?;
        w.write_all(&len.to_le_bytes())?;
        w.write_all(header.as_bytes())?;
        Ok(Self {
            w,
            shape: shape.to_vec(),
            remaining: total,
        })
    }

    /// Appends values in C order.
    pub fn write(&mut self, data: &[f32]) -> std::io::Result<()> {
        if data.len() > self.remaining {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("more data than the shape {:?} holds", self.shape),
            ));
        }
        let mut buf = [0u8; 4096];
        for chunk in data.chunks(buf.len() / 4) {
            for (b, v) in buf.chunks_exact_mut(4).zip(chunk) {
                b.copy_from_slice(&v.to_le_bytes());
            }
            self.w.write_all(&buf[..chunk.len() * 4])?;
        }
        self.remaining -= data.len();
        Ok(())
    }

    /// Checks that the shape is full and flushes; returns the writer.
    pub fn finish(mut self) -> std::io::Result<W> {
        if self.remaining != 0 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "{} values missing for shape {:?}",
                    self.remaining, self.shape
                ),
            ));
        }
        self.w.flush()?;
        Ok(self.w)
    }
}

/// Writes `data` (C order) as a float32 array of `shape`.
pub fn write_f32<W: Write>(w: W, shape: &[usize], data: &[f32]) -> std::io::Result<()> {
    let mut npy = NpyF32Writer::new(w, shape)?;
    npy.write(data)?;
    npy.finish().map(drop)
}

/// Reads a float32 `.npy` file: its shape and data in C order.
pub fn read_f32<R: Read>(mut r: R) -> Result<(Vec<usize>, Vec<f32>), NpyError> {
    let mut magic = [0u8; 8];
    read_exact_or(&mut r, &mut magic, || NpyError::BadMagic)?;
    if &magic[..6] != MAGIC {
        return Err(NpyError::BadMagic);
    }
    let header_len = match magic[6] {
        1 => {
            let mut b = [0u8; 2];
            read_exact_or(&mut r, &mut b, || NpyError::BadHeader("truncated".into()))?;
            usize::from(u16::from_le_bytes(b))
        }
        2 | 3 => {
            let mut b = [0u8; 4];
            read_exact_or(&mut r, &mut b, || NpyError::BadHeader("truncated".into()))?;
            u32::from_le_bytes(b) as usize
        }
        _ => return Err(NpyError::UnsupportedVersion(magic[6], magic[7])),
    };
    if header_len > MAX_HEADER_BYTES {
        return Err(NpyError::BadHeader(format!("{header_len} bytes long")));
    }
    let mut header = vec![0u8; header_len];
    read_exact_or(&mut r, &mut header, || {
        NpyError::BadHeader("truncated".into())
    })?;
    let header =
        std::str::from_utf8(&header).map_err(|_| NpyError::BadHeader("not text".into()))?;
    let (big_endian, shape) = parse_header(header)?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&n| n.checked_mul(4).is_some())
        .ok_or_else(|| NpyError::ShapeTooLarge(shape.clone()))?;
    let expected_bytes = count as u64 * 4;
    let mut bytes = Vec::new();
    r.by_ref().take(expected_bytes).read_to_end(&mut bytes)?;
    if bytes.len() as u64 != expected_bytes {
        return Err(NpyError::Truncated {
            expected_bytes,
            found_bytes: bytes.len() as u64,
        });
    }
    let data = bytes
        .chunks_exact(4)
        .map(|b| {
            let b = [b[0], b[1], b[2], b[3]];
            if big_endian {
                f32::from_be_bytes(b)
            } else {
                f32::from_le_bytes(b)
            }
        })
        .collect();
    Ok((shape, data))
}

fn read_exact_or<R: Read>(
    r: &mut R,
    buf: &mut [u8],
    on_eof: impl FnOnce() -> NpyError,
) -> Result<(), NpyError> {
    r.read_exact(buf).map_err(|e| match e.kind() {
        std::io::ErrorKind::UnexpectedEof => on_eof(),
        _ => NpyError::Io(e),
    })
}

/// Value text following `'key':` in the header dict.
/// Why a header's `shape` value is no tuple of dimensions.
pub(crate) enum ShapeError {
    NotTuple,
    BadDimension(String),
}

/// The dimensions of a header's `shape` value, `(N, H, W)` (a trailing
/// comma allowed): this reader's and `npy_header`'s.
pub(crate) fn shape_tuple(value: &str) -> Result<Vec<usize>, ShapeError> {
    let inner = value
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or(ShapeError::NotTuple)?;
    inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| ShapeError::BadDimension(s.into()))
        })
        .collect()
}

fn field<'a>(header: &'a str, key: &str) -> Result<&'a str, NpyError> {
    let pat = format!("'{key}'");
    let at = header
        .find(&pat)
        .ok_or_else(|| NpyError::BadHeader(format!("no '{key}'")))?;
    let rest = header[at + pat.len()..].trim_start();
    rest.strip_prefix(':')
        .map(str::trim_start)
        .ok_or_else(|| NpyError::BadHeader(format!("no value for '{key}'")))
}

/// (big endian, shape) of a float32 header.
fn parse_header(header: &str) -> Result<(bool, Vec<usize>), NpyError> {
    let descr = field(header, "descr")?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|d| d.split('\'').next())
        .ok_or_else(|| NpyError::BadHeader("descr is not a string".into()))?;
    let big_endian = match descr {
        "<f4" => false,
        ">f4" => true,
        other => return Err(NpyError::UnsupportedDtype(other.to_owned())),
    };
    let fortran = field(header, "fortran_order")?;
    if fortran.starts_with("True") {
        return Err(NpyError::FortranOrder);
    } else if !fortran.starts_with("False") {
        return Err(NpyError::BadHeader("fortran_order is not a bool".into()));
    }
    let shape = shape_tuple(field(header, "shape")?).map_err(|e| match e {
        ShapeError::NotTuple => NpyError::BadHeader("shape is not a tuple".into()),
        ShapeError::BadDimension(s) => NpyError::BadHeader(format!("bad dimension '{s}'")),
    })?;
    Ok((big_endian, shape))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_alignment() {
        let data: Vec<f32> = (0..24).map(|i| i as f32 - 3.5).collect();
        let mut buf = Vec::new();
        write_f32(&mut buf, &[2, 3, 4], &data).unwrap();
        let header_len = u16::from_le_bytes([buf[8], buf[9]]) as usize;
        assert_eq!((10 + header_len) % 64, 0);
        let (shape, back) = read_f32(&buf[..]).unwrap();
        assert_eq!(shape, vec![2, 3, 4]);
        assert_eq!(back, data);
    }

    #[test]
    fn scalar_and_vector_shapes() {
        for shape in [vec![], vec![5usize]] {
            let n: usize = shape.iter().product();
            let mut buf = Vec::new();
            write_f32(&mut buf, &shape, &vec![1.0; n]).unwrap();
            assert_eq!(read_f32(&buf[..]).unwrap().0, shape);
        }
    }

    #[test]
    fn writer_refuses_wrong_amounts() {
        assert!(write_f32(Vec::new(), &[2, 2], &[0.0; 3]).is_err());
        assert!(write_f32(Vec::new(), &[2, 2], &[0.0; 5]).is_err());
        assert!(write_f32(Vec::new(), &[usize::MAX, 2], &[]).is_err());
    }

    fn with_header(h: &str) -> Vec<u8> {
        let mut v = MAGIC.to_vec();
        v.extend([1, 0]);
        v.extend((h.len() as u16).to_le_bytes());
        v.extend(h.as_bytes());
        v
    }

    #[test]
    fn corrupt_inputs_give_typed_errors() {
        let mut good = Vec::new();
        write_f32(&mut good, &[2, 2], &[1.0; 4]).unwrap();
        assert!(matches!(
            read_f32(&b"PK\x03\x04junk"[..]),
            Err(NpyError::BadMagic)
        ));
        assert!(matches!(read_f32(&b""[..]), Err(NpyError::BadMagic)));
        assert!(matches!(
            read_f32(&good[..good.len() - 3]),
            Err(NpyError::Truncated { .. })
        ));
        assert!(matches!(read_f32(&good[..20]), Err(NpyError::BadHeader(_))));
        let mut v9 = good.clone();
        v9[6] = 9;
        assert!(matches!(
            read_f32(&v9[..]),
            Err(NpyError::UnsupportedVersion(9, 0))
        ));
        let f8 = with_header("{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }\n");
        assert!(matches!(
            read_f32(&f8[..]),
            Err(NpyError::UnsupportedDtype(_))
        ));
        let fo = with_header("{'descr': '<f4', 'fortran_order': True, 'shape': (1,), }\n");
        assert!(matches!(read_f32(&fo[..]), Err(NpyError::FortranOrder)));
        let huge = with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999, 99999999999), }\n",
        );
        assert!(matches!(
            read_f32(&huge[..]),
            Err(NpyError::ShapeTooLarge(_))
        ));
        let big =
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (1000000000,), }\n");
        assert!(matches!(
            read_f32(&big[..]),
            Err(NpyError::Truncated { .. })
        ));
        let neg = with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (-1,), }\n");
        assert!(matches!(read_f32(&neg[..]), Err(NpyError::BadHeader(_))));
    }

    /// The headers that made npyz and ndarray-npy panic: a typed error here.
    #[test]
    fn shapes_that_overflow_are_refused() {
        for shape in [
            "(18446744073709551615, 18446744073709551615)",
            "(4294967296, 4294967296, 4294967296)",
            "(99999999999999999999999999,)",
        ] {
            let h = with_header(&format!(
                "{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}\n"
            ));
            assert!(
                matches!(
                    read_f32(&h[..]),
                    Err(NpyError::ShapeTooLarge(_) | NpyError::BadHeader(_))
                ),
                "{shape}"
            );
        }
        // Empty, however long the other side: no data, no allocation.
        let h = with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (0, 18446744073709551615), }\n",
        );
        let (shape, data) = read_f32(&h[..]).unwrap();
        assert_eq!((shape, data.len()), (vec![0, usize::MAX], 0));
    }

    proptest::proptest! {
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..200)) {
            let _ = read_f32(&bytes[..]);
            let mut with_magic = MAGIC.to_vec();
            with_magic.extend(&bytes);
            let _ = read_f32(&with_magic[..]);
        }
    }
}
