//! Reads recordings back, tolerating a torn last record (a killed writer).
//! Nothing in the file is trusted: the header is validated
//! ([`Header::validate`]) and no record may be larger than the largest
//! frame of the header's size, so memory stays bounded by the frame size.

use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::Path;

use crate::format::{self, Decoder, Header, HeaderError, Record};

/// Why a recording cannot be opened.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("cannot read recording: {0}")]
    Io(#[from] io::Error),
    #[error("not an SDI recording (bad magic)")]
    BadMagic,
    #[error("corrupt recording header: {0}")]
    BadHeader(String),
    #[error(transparent)]
    OutOfRange(#[from] HeaderError),
}

/// Sequential reader over a recording's records.
pub struct RecordingReader<R> {
    input: R,
    header: Header,
    /// Width and height every frame record must have.
    size: (usize, usize),
    /// Largest payload accepted (from the header's frame size).
    max_payload: usize,
    /// Set when reading stopped at a torn or corrupt record instead of a clean end.
    damaged_tail: Option<String>,
    finished: bool,
    /// Kept between records: the zstd context and the buffers.
    decoder: Decoder,
    payload: Vec<u8>,
}

impl RecordingReader<BufReader<File>> {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        Self::new(BufReader::new(File::open(path)?))
    }
}

fn read_exact_or_eof<R: Read>(r: &mut R, buf: &mut [u8]) -> io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

impl<R: Read> RecordingReader<R> {
    pub fn new(mut input: R) -> Result<Self, ReadError> {
        let mut magic = [0u8; 8];
        let version = match (read_exact_or_eof(&mut input, &mut magic)?, &magic) {
            (8, m) if m == format::FILE_MAGIC => format::FORMAT_VERSION,
            (8, m) if m == format::FILE_MAGIC_V1 => 1,
            _ => return Err(ReadError::BadMagic),
        };
        let mut len = [0u8; 4];
        input.read_exact(&mut len)?;
        let len = u32::from_le_bytes(len);
        if len > format::MAX_HEADER_BYTES {
            return Err(ReadError::BadHeader(format!("header of {len} bytes")));
        }
        let mut json = vec![0u8; len as usize];
        input.read_exact(&mut json)?;
        let mut crc = [0u8; 4];
        input.read_exact(&mut crc)?;
        if u32::from_le_bytes(crc) != crc32fast::hash(&json) {
            return Err(ReadError::BadHeader("checksum mismatch".into()));
        }
        let header: Header =
            serde_json::from_slice(&json).map_err(|e| ReadError::BadHeader(e.to_string()))?;
        if header.format_version != version {
            return Err(ReadError::BadHeader(format!(
                "format_version {} in a version-{version} file",
                header.format_version
            )));
        }
        header.validate()?;
        Ok(Self {
            input,
            size: (header.sensor.width, header.sensor.height),
            max_payload: header.max_payload_bytes(),
            header,
            damaged_tail: None,
            finished: false,
            decoder: Decoder::default(),
            payload: Vec::new(),
        })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    /// `Some(reason)` when the file ended in a torn or corrupt record.
    pub fn damaged_tail(&self) -> Option<&str> {
        self.damaged_tail.as_deref()
    }

    /// The next intact record; `None` at the end of the file or at the first damaged record.
    pub fn next_record(&mut self) -> Option<Record> {
        if self.finished {
            return None;
        }
        match self.read_record() {
            Ok(Some(r)) => Some(r),
            Ok(None) => {
                self.finished = true;
                None
            }
            Err(why) => {
                self.finished = true;
                self.damaged_tail = Some(why);
                None
            }
        }
    }

    fn read_record(&mut self) -> Result<Option<Record>, String> {
        let mut head = [0u8; 9];
        let n = read_exact_or_eof(&mut self.input, &mut head).map_err(|e| e.to_string())?;
        if n == 0 {
            return Ok(None);
        }
        if n < head.len() {
            return Err(format!("torn record header ({n} of 9 bytes)"));
        }
        if &head[..4] != format::RECORD_MAGIC {
            return Err("bad record magic".into());
        }
        let kind = head[4];
        let len = u32::from_le_bytes([head[5], head[6], head[7], head[8]]);
        if len as usize > self.max_payload {
            return Err(format!(
                "record length {len} exceeds {} (the largest frame record of this size)",
                self.max_payload
            ));
        }
        self.payload.resize(len as usize + 4, 0);
        let n = read_exact_or_eof(&mut self.input, &mut self.payload).map_err(|e| e.to_string())?;
        if n < self.payload.len() {
            return Err(format!("torn record ({n} of {} bytes)", self.payload.len()));
        }
        let (payload, crc_bytes) = self.payload.split_at(len as usize);
        let crc = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
        if crc != format::record_crc(kind, payload) {
            return Err("record checksum mismatch".into());
        }
        self.decoder
            .decode(kind, payload, self.size)
            .map(Some)
            .map_err(|e| e.to_string())
    }
}

impl<R: Read> Iterator for RecordingReader<R> {
    type Item = Record;
    fn next(&mut self) -> Option<Record> {
        self.next_record()
    }
}
