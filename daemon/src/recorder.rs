//! sdid's recorder: a thread appending records ([`RecordingFile`]) behind a
//! [`Bounded`] queue. The frame loop never waits on the disk: frames that do
//! not fit the queue are counted as dropped, and finishing (draining the
//! queue, end record, fsync) happens on the recorder thread while the
//! caller waits at most a given time. The recorder stops by itself, with an
//! end record and a [`StopCause`], at `[recording] max_bytes`, at the
//! free-space floor `min_free_bytes`, or when the disk is full.

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver};
use std::sync::Arc;
use std::time::Duration;

use sdi_core::{Frame, Image};
use sdi_recording::{Header, RecordingFile};
use tokio::sync::oneshot;

use sdi_config::RecordingSection;

use crate::queue::{Bounded, Offer};

/// Frames queued between the frame loop and the disk.
pub const QUEUE_FRAMES: usize = 64;
/// Bytes of an end record (magic, kind, length, 16-byte payload, CRC):
/// kept free below `max_bytes` so a limited recording still ends cleanly.
const END_RECORD_BYTES: u64 = 4 + 1 + 4 + 16 + 4;

enum Msg {
    Frame { mode: &'static str, frame: Frame },
    Dark { frames: u32, dn: Image<f32> },
}

/// Counters shared by the frame loop and the writer thread.
#[derive(Debug, Default)]
pub struct Counters {
    pub written: AtomicU64,
    /// Shared with the queue, which counts what did not fit.
    pub dropped: Arc<AtomicU64>,
    /// Bytes in the file (whole records).
    pub bytes: AtomicU64,
    /// Set when the recorder stopped by itself ([`StopCause`]).
    pub ended: AtomicBool,
}

/// What a finished recording contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Summary {
    pub frames: u64,
    pub dropped: u64,
    pub bytes: u64,
}

/// Why the recorder stopped before it was asked to.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StopCause {
    #[error("the recording reached [recording] max_bytes = {max_bytes}")]
    MaxBytes { max_bytes: u64 },
    #[error("free space fell to {free_bytes} bytes, below [recording] min_free_bytes = {min_free_bytes}")]
    FreeSpace {
        free_bytes: u64,
        min_free_bytes: u64,
    },
    #[error("the disk is full: {0}")]
    DiskFull(String),
    #[error("write error: {0}")]
    Io(String),
}

impl StopCause {
    fn of(e: &io::Error) -> Self {
        if e.raw_os_error() == Some(libc::ENOSPC) || e.raw_os_error() == Some(libc::EDQUOT) {
            StopCause::DiskFull(e.to_string())
        } else {
            StopCause::Io(e.to_string())
        }
    }
}

/// Why [`RecordingWriter::finish_within`] gave no summary.
#[derive(Debug, thiserror::Error)]
pub enum FinishError {
    #[error("finishing the recording: {0}")]
    Io(#[from] io::Error),
    #[error("storage did not finish the recording within {waited:?}: {queued} queued frames and the end record are still being written in the background")]
    TimedOut { waited: Duration, queued: u64 },
    #[error("the recorder thread died")]
    Died,
}

/// Handle to a recording in progress.
pub struct RecordingWriter {
    path: PathBuf,
    queue: Bounded<Msg>,
    counters: Arc<Counters>,
    /// The thread's result once it has written the end record and synced.
    done: Receiver<io::Result<()>>,
    /// Fires once if the recorder stops by itself.
    ended: Option<oneshot::Receiver<StopCause>>,
    queued: Arc<AtomicU64>,
}

impl RecordingWriter {
    /// Creates `path` (which must not exist), writes the header and starts the writer thread.
    pub fn create(path: &Path, header: &Header, limits: RecordingSection) -> io::Result<Self> {
        let file = RecordingFile::create(path, header)?;
        Self::start(file, path, limits)
    }

    /// Records into `file`, an empty file opened for writing by someone else
    /// (a client passing its descriptor over D-Bus); `label` names it in
    /// status output only and is never opened.
    pub fn from_file(
        file: File,
        label: &Path,
        header: &Header,
        limits: RecordingSection,
    ) -> io::Result<Self> {
        Self::start(RecordingFile::from_file(file, header)?, label, limits)
    }

    fn start(file: RecordingFile, label: &Path, limits: RecordingSection) -> io::Result<Self> {
        let (done_tx, done) = mpsc::channel();
        let (ended_tx, ended) = oneshot::channel();
        let counters = Arc::new(Counters::default());
        counters
            .bytes
            .store(file.bytes_written(), Ordering::Relaxed);
        let queued = Arc::new(AtomicU64::new(0));
        let (c, q) = (counters.clone(), queued.clone());
        let dropped = counters.dropped.clone();
        let queue = Bounded::spawn_counting("sdid-recorder", QUEUE_FRAMES, dropped, move |rx| {
            let r = run(file, rx, &c, &q, limits, ended_tx);
            let _ = done_tx.send(r);
        })?;
        Ok(Self {
            path: label.to_owned(),
            queue,
            counters,
            done,
            ended: Some(ended),
            queued,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn counters(&self) -> &Arc<Counters> {
        &self.counters
    }

    /// True once the recorder stopped by itself (limit, disk full).
    pub fn ended(&self) -> bool {
        self.counters.ended.load(Ordering::Relaxed)
    }

    /// The notice of the recorder stopping by itself; taken once.
    pub fn take_ended(&mut self) -> Option<oneshot::Receiver<StopCause>> {
        self.ended.take()
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
        if self.ended() {
            return false;
        }
        // Counted before the offer: the thread takes it off at once.
        self.queued.fetch_add(1, Ordering::Relaxed);
        match self.queue.offer(msg) {
            Offer::Queued => true,
            Offer::Dropped => {
                self.queued.fetch_sub(1, Ordering::Relaxed);
                false
            }
            Offer::Gone => {
                self.queued.fetch_sub(1, Ordering::Relaxed);
                self.queue.count_drop();
                false
            }
        }
    }

    fn summary(&self) -> Summary {
        Summary {
            frames: self.counters.written.load(Ordering::Relaxed),
            dropped: self.counters.dropped.load(Ordering::Relaxed),
            bytes: self.counters.bytes.load(Ordering::Relaxed),
        }
    }

    /// Closes the queue and waits up to `timeout` for the recorder thread
    /// to write what is queued and the end record and to sync. On time-out
    /// the thread goes on alone (the file is closed when it is done).
    pub fn finish_within(mut self, timeout: Duration) -> Result<Summary, FinishError> {
        self.queue.close();
        match self.done.recv_timeout(timeout) {
            Ok(r) => r.map(|()| self.summary()).map_err(FinishError::Io),
            Err(mpsc::RecvTimeoutError::Timeout) => Err(FinishError::TimedOut {
                waited: timeout,
                queued: self.queued.load(Ordering::Relaxed),
            }),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(FinishError::Died),
        }
    }
}

// Dropping a writer closes its queue ([`Bounded`]); the thread finishes
// the file on its own (never on the dropping thread).

/// Checks the limits for a record of `len` bytes about to be written.
fn check_limits(
    file: &RecordingFile,
    len: u64,
    limits: &RecordingSection,
) -> Result<(), StopCause> {
    if let Some(max_bytes) = limits.max_bytes {
        if file.bytes_written() + len + END_RECORD_BYTES > max_bytes {
            return Err(StopCause::MaxBytes { max_bytes });
        }
    }
    if limits.min_free_bytes > 0 {
        // fstatvfs: about a microsecond, cheap next to encoding a frame
        let free_bytes = file.free_bytes().map_err(|e| StopCause::of(&e))?;
        if free_bytes < limits.min_free_bytes.saturating_add(len) {
            return Err(StopCause::FreeSpace {
                free_bytes,
                min_free_bytes: limits.min_free_bytes,
            });
        }
    }
    Ok(())
}

fn run(
    mut file: RecordingFile,
    rx: Receiver<Msg>,
    counters: &Counters,
    queued: &AtomicU64,
    limits: RecordingSection,
    ended: oneshot::Sender<StopCause>,
) -> io::Result<()> {
    let stop = loop {
        let Ok(msg) = rx.recv() else { break None };
        queued.fetch_sub(1, Ordering::Relaxed);
        let (len, is_frame) = match &msg {
            Msg::Frame { mode, frame } => (file.encode_frame(mode, frame), true),
            Msg::Dark { frames, dn } => (file.encode_dark(*frames, dn), false),
        };
        if let Err(cause) = check_limits(&file, len as u64, &limits) {
            break Some(cause);
        }
        if let Err(e) = file.write_encoded().and_then(|()| file.sync_if_due()) {
            break Some(StopCause::of(&e));
        }
        counters
            .bytes
            .store(file.bytes_written(), Ordering::Relaxed);
        if is_frame {
            counters.written.fetch_add(1, Ordering::Relaxed);
        }
    };
    let written = counters.written.load(Ordering::Relaxed);
    let Some(cause) = stop else {
        let dropped = counters.dropped.load(Ordering::Relaxed);
        return file.finish(written, dropped);
    };
    counters.ended.store(true, Ordering::Relaxed);
    drop(rx);
    let dropped = counters.dropped.load(Ordering::Relaxed);
    tracing::error!(frames = written, "recording stopped: {cause}");
    // Every whole record stays readable; the end record may not fit a full disk.
    let end = file.finish(written, dropped);
    if let Err(e) = &end {
        tracing::warn!("recording has no end record: {e}");
    }
    let _ = ended.send(cause);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_core::sensor::SensorPreset;
    use sdi_recording::{Record, RecordingReader};
    use std::io::Read;

    fn header(w: usize, h: usize) -> Header {
        let mut sensor = SensorPreset::TiOpt8241.params();
        sensor.width = w;
        sensor.height = h;
        Header {
            format_version: 2,
            ..Header::for_sensor("raw", "sim", sensor)
        }
    }

    fn noisy_frame(w: usize, h: usize, seq: u64) -> Frame {
        let mut f = Frame::new(w, h);
        let mut x = seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        for v in &mut f.dn.data {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = (x % 4096) as f32 - 2048.0;
        }
        f.sequence = seq;
        f
    }

    /// Storage that takes nothing (a FIFO nobody reads: writes block, as on
    /// a frozen file system): pushing never blocks, frames that do not fit
    /// the queue are dropped, finishing gives up after its time-out, and
    /// once the storage drains the recording completes with an end record.
    #[test]
    fn frozen_storage_never_blocks_the_pusher_and_finishing_is_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("frozen");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&fifo)
            .unwrap();
        let limits = RecordingSection {
            max_bytes: None,
            min_free_bytes: 0,
        };
        let (w, h) = (64, 48);
        let rec = RecordingWriter::from_file(file, &fifo, &header(w, h), limits).unwrap();
        for seq in 1..=500 {
            rec.push_frame("raw", &noisy_frame(w, h, seq));
        }
        let dropped = rec.counters().dropped.load(Ordering::Relaxed);
        assert!(
            dropped >= 500 - QUEUE_FRAMES as u64 - 32,
            "{dropped} dropped"
        );
        match rec.finish_within(Duration::from_millis(200)) {
            Err(FinishError::TimedOut { queued, .. }) => assert!(queued > 0),
            other => panic!("{other:?}"),
        }
        // Thaw: read everything; the recorder finishes and closes the file.
        let mut bytes = Vec::new();
        std::fs::File::open(&fifo)
            .unwrap()
            .read_to_end(&mut bytes)
            .unwrap();
        let mut r = RecordingReader::new(std::io::Cursor::new(bytes)).unwrap();
        let recs: Vec<Record> = r.by_ref().collect();
        assert_eq!(r.damaged_tail(), None);
        let frames = recs
            .iter()
            .filter(|x| matches!(x, Record::Frame { .. }))
            .count() as u64;
        assert_eq!(
            recs.last(),
            Some(&Record::End {
                frames,
                dropped: 500 - frames
            })
        );
    }

    /// The size limit stops the recorder by itself with an end record and
    /// a [`StopCause`], and the file stays within the limit.
    #[test]
    fn max_bytes_ends_the_recording_with_a_cause() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.sdirec");
        let limits = RecordingSection {
            max_bytes: Some(40_000),
            min_free_bytes: 0,
        };
        let (w, h) = (64, 48);
        let mut rec = RecordingWriter::create(&path, &header(w, h), limits).unwrap();
        let ended = rec.take_ended().unwrap();
        let mut seq = 0;
        while !rec.ended() && seq < 10_000 {
            seq += 1;
            if !rec.push_frame("raw", &noisy_frame(w, h, seq)) {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        assert_eq!(
            ended.blocking_recv(),
            Ok(StopCause::MaxBytes { max_bytes: 40_000 })
        );
        let summary = rec.finish_within(Duration::from_secs(10)).unwrap();
        assert!(std::fs::metadata(&path).unwrap().len() <= 40_000);
        let mut r = RecordingReader::open(&path).unwrap();
        let recs: Vec<Record> = r.by_ref().collect();
        assert_eq!(r.damaged_tail(), None);
        assert!(summary.frames >= 1);
        assert!(
            matches!(recs.last(), Some(Record::End { frames, .. }) if *frames == summary.frames)
        );
    }
}
