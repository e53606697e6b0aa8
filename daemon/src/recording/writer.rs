//! Appends records to a recording on its own thread behind a bounded queue:
//! the frame loop never waits on the disk; frames that do not fit are counted
//! as dropped.

use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use sdi_core::{Frame, Image};

use super::format::{self, Header};

/// Frames queued between the frame loop and the disk.
pub const QUEUE_FRAMES: usize = 64;

enum Msg {
    Frame { mode: &'static str, frame: Frame },
    Dark { frames: u32, dn: Image<f32> },
}

/// Counters shared by the frame loop and the writer thread.
#[derive(Debug, Default)]
pub struct Counters {
    pub written: AtomicU64,
    pub dropped: AtomicU64,
}

/// What a finished recording contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Summary {
    pub frames: u64,
    pub dropped: u64,
}

/// Handle to a recording in progress.
pub struct RecordingWriter {
    path: PathBuf,
    tx: Option<SyncSender<Msg>>,
    counters: Arc<Counters>,
    thread: Option<JoinHandle<io::Result<()>>>,
}

impl RecordingWriter {
    /// Creates `path` (which must not exist), writes the header and starts the writer thread.
    pub fn create(path: &Path, header: &Header) -> io::Result<Self> {
        let file = OpenOptions::new().write(true).create_new(true).open(path)?;
        Self::from_file(file, path, header)
    }

    /// Records into `file`, an empty file opened for writing by someone else
    /// (a client passing its descriptor over D-Bus); `label` names it in
    /// status output only and is never opened.
    pub fn from_file(mut file: File, label: &Path, header: &Header) -> io::Result<Self> {
        let json = serde_json::to_vec(header).map_err(io::Error::other)?;
        let mut head = Vec::with_capacity(json.len() + 16);
        head.extend_from_slice(format::FILE_MAGIC);
        head.extend_from_slice(&(json.len() as u32).to_le_bytes());
        head.extend_from_slice(&json);
        head.extend_from_slice(&crc32fast::hash(&json).to_le_bytes());
        file.write_all(&head)?;
        let (tx, rx) = sync_channel(QUEUE_FRAMES);
        let counters = Arc::new(Counters::default());
        let c = counters.clone();
        let thread = std::thread::Builder::new()
            .name("sdid-recorder".into())
            .spawn(move || run(file, rx, c))?;
        Ok(Self {
            path: label.to_owned(),
            tx: Some(tx),
            counters,
            thread: Some(thread),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn counters(&self) -> &Arc<Counters> {
        &self.counters
    }

    /// Queues a sensor frame; never blocks. Returns false (and counts a drop) when the queue is full.
    pub fn push_frame(&self, mode: &'static str, frame: &Frame) -> bool {
        self.push(Msg::Frame {
            mode,
            frame: frame.clone(),
        })
    }

    /// Queues the dark frame in force; never blocks.
    pub fn push_dark(&self, frames: u32, dn: &Image<f32>) -> bool {
        self.push(Msg::Dark {
            frames,
            dn: dn.clone(),
        })
    }

    fn push(&self, msg: Msg) -> bool {
        let Some(tx) = &self.tx else { return false };
        match tx.try_send(msg) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Flushes the queue, writes the end record, syncs and closes the file.
    pub fn finish(mut self) -> io::Result<Summary> {
        self.finish_inner()
    }

    fn finish_inner(&mut self) -> io::Result<Summary> {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            t.join()
                .map_err(|_| io::Error::other("recorder thread panicked"))??;
        }
        Ok(Summary {
            frames: self.counters.written.load(Ordering::Relaxed),
            dropped: self.counters.dropped.load(Ordering::Relaxed),
        })
    }
}

impl Drop for RecordingWriter {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.finish_inner();
        }
    }
}

fn write_record(file: &mut File, kind: u8, payload: &[u8], buf: &mut Vec<u8>) -> io::Result<()> {
    buf.clear();
    buf.extend_from_slice(format::RECORD_MAGIC);
    buf.push(kind);
    buf.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    buf.extend_from_slice(payload);
    buf.extend_from_slice(&format::record_crc(kind, payload).to_le_bytes());
    // One write per record: after it returns the record is in the kernel's
    // page cache and survives the death of this process.
    file.write_all(buf)
}

fn run(mut file: File, rx: Receiver<Msg>, counters: Arc<Counters>) -> io::Result<()> {
    let mut payload = Vec::new();
    let mut buf = Vec::new();
    let mut last_sync = Instant::now();
    while let Ok(msg) = rx.recv() {
        match msg {
            Msg::Frame { mode, frame } => {
                format::encode_frame(mode, &frame, &mut payload);
                write_record(&mut file, format::KIND_FRAME, &payload, &mut buf)?;
                counters.written.fetch_add(1, Ordering::Relaxed);
            }
            Msg::Dark { frames, dn } => {
                format::encode_dark(frames, &dn, &mut payload);
                write_record(&mut file, format::KIND_DARK, &payload, &mut buf)?;
            }
        }
        if last_sync.elapsed() > Duration::from_secs(1) {
            file.sync_data()?;
            last_sync = Instant::now();
        }
    }
    format::encode_end(
        counters.written.load(Ordering::Relaxed),
        counters.dropped.load(Ordering::Relaxed),
        &mut payload,
    );
    write_record(&mut file, format::KIND_END, &payload, &mut buf)?;
    file.sync_all()
}
