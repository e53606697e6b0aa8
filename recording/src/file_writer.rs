//! Appends records to a recording file: pure I/O, on the caller's thread.
//! (sdid runs it on its recorder thread, behind a queue.)

use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use sdi_core::{Frame, Image};

use crate::format::{self, Header};

/// How often written data is `fdatasync`ed (power loss may lose this much).
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);

/// An open recording: header written, records appended one `write(2)` each.
pub struct RecordingFile {
    file: File,
    /// Bytes in the file that hold whole records (and the header).
    bytes: u64,
    payload: Vec<u8>,
    scratch: Vec<u8>,
    record: Vec<u8>,
    last_sync: Instant,
}

impl RecordingFile {
    /// Creates `path` (which must not exist) and writes the header.
    pub fn create(path: &Path, header: &Header) -> io::Result<Self> {
        let file = OpenOptions::new().write(true).create_new(true).open(path)?;
        Self::from_file(file, header)
    }

    /// Writes the header (as the current format version) into `file`, an
    /// empty file open for writing.
    pub fn from_file(mut file: File, header: &Header) -> io::Result<Self> {
        let header = Header {
            format_version: format::FORMAT_VERSION,
            ..header.clone()
        };
        let head = format::header_bytes(format::FILE_MAGIC, &header).map_err(io::Error::other)?;
        file.write_all(&head)?;
        Ok(Self {
            file,
            bytes: head.len() as u64,
            payload: Vec::new(),
            scratch: Vec::new(),
            record: Vec::new(),
            last_sync: Instant::now(),
        })
    }

    /// Bytes of whole records (and header) written so far.
    pub fn bytes_written(&self) -> u64 {
        self.bytes
    }

    /// Encodes a frame record without writing it; returns its size in
    /// bytes, so the caller can check a size limit first. Write it with
    /// [`Self::write_encoded`].
    pub fn encode_frame(&mut self, mode: &str, frame: &Frame) -> usize {
        format::encode_frame(mode, frame, &mut self.payload, &mut self.scratch);
        format::record_bytes(format::KIND_FRAME, &self.payload, &mut self.record);
        self.record.len()
    }

    /// Encodes a dark-frame record without writing it; returns its size.
    pub fn encode_dark(&mut self, frames: u32, dn: &Image<f32>) -> usize {
        format::encode_dark(frames, dn, &mut self.payload);
        format::record_bytes(format::KIND_DARK, &self.payload, &mut self.record);
        self.record.len()
    }

    /// Writes the record last encoded, in one `write(2)` (after it returns
    /// the record is in the page cache and survives the death of the
    /// process). On error (disk full, ...) the file is cut back to its last
    /// whole record, best effort, so that what was written stays readable.
    pub fn write_encoded(&mut self) -> io::Result<()> {
        match self.file.write_all(&self.record) {
            Ok(()) => {
                self.bytes += self.record.len() as u64;
                Ok(())
            }
            Err(e) => {
                let _ = self.file.set_len(self.bytes);
                Err(e)
            }
        }
    }

    /// `fdatasync` when [`SYNC_INTERVAL`] has passed since the last one.
    pub fn sync_if_due(&mut self) -> io::Result<()> {
        if self.last_sync.elapsed() >= SYNC_INTERVAL {
            self.file.sync_data()?;
            self.last_sync = Instant::now();
        }
        Ok(())
    }

    /// Free bytes an unprivileged writer may still use on the file's file system.
    pub fn free_bytes(&self) -> io::Result<u64> {
        let s = nix::sys::statvfs::fstatvfs(&self.file).map_err(io::Error::from)?;
        Ok((s.blocks_available() as u64).saturating_mul(s.fragment_size() as u64))
    }

    /// Writes the end record and syncs the file.
    pub fn finish(mut self, frames: u64, dropped: u64) -> io::Result<()> {
        format::encode_end(frames, dropped, &mut self.payload);
        format::record_bytes(format::KIND_END, &self.payload, &mut self.record);
        self.write_encoded()?;
        self.file.sync_all()
    }

    /// Syncs what was written without an end record (the recording was
    /// cut short: disk full, size limit); readers see every whole record.
    pub fn abandon(self) -> io::Result<()> {
        self.file.sync_all()
    }
}
