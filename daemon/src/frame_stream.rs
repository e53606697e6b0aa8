//! Frame streams (`StreamFrames`): every mode output written into a pipe or
//! socket a client passed, in `sdi_api::frame_stream`'s format (its body
//! encoded once per frame for every stream: [`OutFrame::stream_body`]),
//! each stream behind a two-slot [`Bounded`] queue on a thread of its own,
//! so a slow or stalled reader loses frames and the frame loop never waits.
//!
//! A stream belongs to the bus connection that opened it: one connection
//! holds at most [`MAX_STREAMS_PER_PEER`] of the [`MAX_STREAMS`], and its
//! streams end when it leaves the bus ([`FrameStreams::close_owner`]). The
//! threads never block in a write (sockets: `MSG_DONTWAIT` on each send;
//! pipes: `O_NONBLOCK`), so a closed stream's thread ends within
//! [`WRITE_POLL`]. A stream whose reader closed its end frees its slot
//! without waiting for a frame: the next `open` sees the hang-up at once,
//! and an idle stream's thread looks every [`WRITE_POLL`] (a client that
//! opens a stream per frame at 0.5 fps would otherwise hold its slots for
//! 2 s after each close).

use std::fs::File;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::Duration;

use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::socket::{send, MsgFlags};
use sdi_api::frame_stream::{FrameHeader, WireError};
use sdi_core::display::DisplayRange;

use crate::out_frame::OutFrame;
use crate::queue::{Bounded, Offer};

/// Streams open at once; one more is refused.
pub const MAX_STREAMS: usize = 4;
/// Streams one bus connection may hold: room is left for another client
/// (`sdictl view` takes one).
pub const MAX_STREAMS_PER_PEER: usize = 2;
/// Longest a stream's thread waits for room in the reader's buffer before
/// it looks whether the stream was closed, ms.
const WRITE_POLL_MS: u16 = 100;
/// [`WRITE_POLL_MS`] as a duration.
pub const WRITE_POLL: Duration = Duration::from_millis(WRITE_POLL_MS as u64);
/// Frames queued per stream: one being written, one waiting.
const QUEUE_FRAMES: usize = 2;

/// Why a stream was not opened.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    #[error("{MAX_STREAMS} frame streams are open already")]
    TooMany,
    #[error(
        "this connection holds {MAX_STREAMS_PER_PEER} frame streams already (the most one \
         connection may hold; they end when it closes them or leaves the bus)"
    )]
    TooManyForPeer,
    #[error("starting the stream's thread: {0}")]
    Thread(#[source] std::io::Error),
}

/// Where a stream's frames go, as `client_fd::stream_target` accepted it.
#[derive(Debug)]
pub enum StreamTarget {
    /// A pipe's or FIFO's writing end (opened write-only), made non-blocking.
    Pipe(File),
    /// A connected Unix stream socket, shut down for reading by sdid.
    Socket(OwnedFd),
}

impl StreamTarget {
    fn fd(&self) -> std::os::fd::BorrowedFd<'_> {
        match self {
            StreamTarget::Pipe(f) => f.as_fd(),
            StreamTarget::Socket(s) => s.as_fd(),
        }
    }

    /// True once the reader closed its end: a pipe's writing end polls
    /// POLLERR, a socket whose peer closed POLLHUP (both reported whatever
    /// the events asked for). Never waits.
    fn reader_gone(&self) -> bool {
        let mut fds = [PollFd::new(self.fd(), PollFlags::empty())];
        match poll(&mut fds, PollTimeout::ZERO) {
            Ok(0) | Err(Errno::EINTR) => false,
            Ok(_) => fds[0].revents().is_some_and(|r| {
                r.intersects(PollFlags::POLLERR | PollFlags::POLLHUP | PollFlags::POLLNVAL)
            }),
            Err(_) => true,
        }
    }
}

/// Why a stream ended (logged at debug level: a client closing is normal).
#[derive(Debug, thiserror::Error)]
enum WriteError {
    #[error("writing to the client: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Wire(#[from] WireError),
    #[error("closed by sdid (the caller left the bus)")]
    Closed,
}

struct Stream {
    queue: Bounded<Arc<OutFrame>>,
    /// The unique bus name of the connection that opened it.
    owner: String,
    /// Set to end the stream's thread at its next wait.
    closed: Arc<AtomicBool>,
    /// Set by the thread when it ends (the reader went away).
    ended: Arc<AtomicBool>,
    /// Shared with the thread: to see at `open` that the reader left.
    target: Arc<StreamTarget>,
}

impl Stream {
    /// False once the stream's thread ended or its reader closed its end;
    /// then the thread is told to end.
    fn live(&self) -> bool {
        if self.ended.load(Ordering::Relaxed) || self.target.reader_gone() {
            self.closed.store(true, Ordering::Relaxed);
            return false;
        }
        true
    }
}

/// The open streams, held by the frame loop.
#[derive(Default)]
pub struct FrameStreams {
    streams: Vec<Stream>,
}

impl FrameStreams {
    /// Starts writing frames into `target` for the connection `owner`.
    pub fn open(&mut self, target: StreamTarget, owner: &str) -> Result<(), StreamError> {
        self.streams.retain(Stream::live);
        if self.streams.iter().filter(|s| s.owner == owner).count() >= MAX_STREAMS_PER_PEER {
            return Err(StreamError::TooManyForPeer);
        }
        if self.streams.len() >= MAX_STREAMS {
            return Err(StreamError::TooMany);
        }
        let dropped = Arc::new(AtomicU64::new(0));
        let closed = Arc::new(AtomicBool::new(false));
        let ended = Arc::new(AtomicBool::new(false));
        let target = Arc::new(target);
        let (seen, stop, done) = (dropped.clone(), closed.clone(), ended.clone());
        let to = target.clone();
        let queue = Bounded::spawn_counting("sdid-stream", QUEUE_FRAMES, dropped, move |rx| {
            if let Err(e) = write_frames(&to, &rx, &seen, &stop) {
                tracing::debug!("frame stream ended: {e}");
            }
            done.store(true, Ordering::Relaxed);
        })
        .map_err(StreamError::Thread)?;
        self.streams.push(Stream {
            queue,
            owner: owner.to_owned(),
            closed,
            ended,
            target,
        });
        Ok(())
    }

    /// Ends the streams of `owner` (it left the bus): their slots are free
    /// at once, their threads end within [`WRITE_POLL`].
    pub fn close_owner(&mut self, owner: &str) {
        self.streams.retain(|s| {
            let theirs = s.owner == owner;
            if theirs {
                s.closed.store(true, Ordering::Relaxed);
            }
            !theirs
        });
    }

    pub fn len(&self) -> usize {
        self.streams.len()
    }

    pub fn is_empty(&self) -> bool {
        self.streams.is_empty()
    }

    /// Queues `frame` on every stream; never blocks. A full queue drops the
    /// frame (counted in the stream's headers), a closed stream is removed.
    pub fn send(&mut self, frame: &Arc<OutFrame>) {
        self.streams
            .retain(|s| s.queue.offer(frame.clone()) != Offer::Gone);
    }
}

/// The stream's thread: encodes and writes until the reader goes away or
/// the stream is closed; while no frame comes it looks for either every
/// [`WRITE_POLL`].
fn write_frames(
    target: &StreamTarget,
    rx: &Receiver<Arc<OutFrame>>,
    dropped: &AtomicU64,
    closed: &AtomicBool,
) -> Result<(), WriteError> {
    loop {
        let frame = match rx.recv_timeout(WRITE_POLL) {
            Ok(p) => p,
            Err(RecvTimeoutError::Disconnected) => return Ok(()),
            Err(RecvTimeoutError::Timeout) if closed.load(Ordering::Relaxed) => {
                return Err(WriteError::Closed)
            }
            Err(RecvTimeoutError::Timeout) if target.reader_gone() => {
                return Err(std::io::Error::from(std::io::ErrorKind::BrokenPipe).into())
            }
            Err(RecvTimeoutError::Timeout) => continue,
        };
        let out = &frame.output;
        let img = &out.signed_dn;
        let header = FrameHeader {
            sequence: out.sequence,
            timestamp_us: out.timestamp_us,
            width: img.width as u32,
            height: img.height as u32,
            max_abs_dn: match frame.display.range {
                DisplayRange::SymmetricAuto => 0.0,
                DisplayRange::Fixed { max_abs_dn } => max_abs_dn,
            },
            dropped: dropped.load(Ordering::Relaxed),
            mode: frame.mode.name().to_owned(),
            colormap: frame.display.colormap.name().to_owned(),
            has_channels: out.channels.is_some(),
        };
        write_all(target, &header.encode()?, closed)?;
        write_all(target, &frame.stream_body(), closed)?;
    }
}

/// Writes `buf` without ever blocking in the kernel: on a full buffer it
/// waits up to [`WRITE_POLL`] for room, then looks at `closed` again.
fn write_all(target: &StreamTarget, mut buf: &[u8], closed: &AtomicBool) -> Result<(), WriteError> {
    let fd = target.fd();
    while !buf.is_empty() {
        if closed.load(Ordering::Relaxed) {
            return Err(WriteError::Closed);
        }
        let written = match target {
            StreamTarget::Pipe(f) => nix::unistd::write(f, buf),
            StreamTarget::Socket(s) => send(
                s.as_raw_fd(),
                buf,
                MsgFlags::MSG_DONTWAIT | MsgFlags::MSG_NOSIGNAL,
            ),
        };
        match written {
            Ok(0) => return Err(std::io::Error::from(std::io::ErrorKind::WriteZero).into()),
            Ok(n) => buf = &buf[n..],
            Err(Errno::EAGAIN | Errno::EINTR) => {
                let mut fds = [PollFd::new(fd, PollFlags::POLLOUT)];
                match poll(&mut fds, PollTimeout::from(WRITE_POLL_MS)) {
                    Ok(_) | Err(Errno::EINTR) => {}
                    Err(e) => return Err(std::io::Error::from(e).into()),
                }
            }
            Err(e) => return Err(std::io::Error::from(e).into()),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_api::frame_stream::{get_f32s, HEADER_BYTES};
    use sdi_core::display::DisplayMap;
    use sdi_core::mode::{ModeId, ModeOutput};
    use std::io::Read;
    use std::os::unix::net::UnixStream;

    fn out_frame(out: ModeOutput) -> Arc<OutFrame> {
        Arc::new(OutFrame::new(
            out,
            ModeId::DirectOnly,
            DisplayMap::default(),
        ))
    }

    #[test]
    fn a_peer_holds_two_slots_and_its_leaving_ends_its_streams() {
        let mut streams = FrameStreams::default();
        let mut readers = Vec::new();
        let mut open = |streams: &mut FrameStreams, owner: &str| {
            let (ours, theirs) = UnixStream::pair().unwrap();
            readers.push(theirs);
            streams.open(StreamTarget::Socket(ours.into()), owner)
        };
        open(&mut streams, ":1.1").unwrap();
        open(&mut streams, ":1.1").unwrap();
        assert!(matches!(
            open(&mut streams, ":1.1"),
            Err(StreamError::TooManyForPeer)
        ));
        open(&mut streams, ":1.2").unwrap();
        open(&mut streams, ":1.2").unwrap();
        assert!(matches!(
            open(&mut streams, ":1.3"),
            Err(StreamError::TooMany)
        ));
        // Frames fill the readers' buffers (nobody reads), then :1.1 leaves.
        let out = out_frame(ModeOutput::new(64, 64));
        for _ in 0..64 {
            streams.send(&out);
        }
        streams.close_owner(":1.1");
        assert_eq!(streams.len(), 2);
        open(&mut streams, ":1.3").unwrap();
        // Its threads end (they never block in a write): its readers see the end.
        for r in &mut readers[..2] {
            r.set_read_timeout(Some(std::time::Duration::from_secs(5)))
                .unwrap();
            let mut buf = vec![0u8; 1 << 16];
            while r.read(&mut buf).unwrap() > 0 {}
        }
    }

    /// A client that opens a stream per frame and closes it when it has
    /// one (or gave up waiting) gets its slots back without a frame being
    /// written: at the next `open` for sockets and pipes alike, and the
    /// idle thread ends within a few `WRITE_POLL`s.
    #[test]
    fn a_reader_that_closed_frees_its_slot_before_any_frame() {
        let mut streams = FrameStreams::default();
        for _ in 0..5 {
            let (ours, theirs) = UnixStream::pair().unwrap();
            streams
                .open(StreamTarget::Socket(ours.into()), ":1.1")
                .unwrap();
            drop(theirs);
        }
        for _ in 0..5 {
            let (read, write) = nix::unistd::pipe().unwrap();
            streams
                .open(StreamTarget::Pipe(File::from(write)), ":1.1")
                .unwrap();
            drop(read);
        }
        let (ours, _reader) = UnixStream::pair().unwrap();
        streams
            .open(StreamTarget::Socket(ours.into()), ":1.1")
            .unwrap();
        assert_eq!(streams.len(), 1, "only the stream whose reader is there");
        // Nobody opens again: the idle thread sees its reader leave.
        let (ours, theirs) = UnixStream::pair().unwrap();
        streams
            .open(StreamTarget::Socket(ours.into()), ":1.2")
            .unwrap();
        drop(theirs);
        let ended = streams.streams[1].ended.clone();
        let t0 = std::time::Instant::now();
        while !ended.load(Ordering::Relaxed) {
            assert!(
                t0.elapsed() < 50 * WRITE_POLL,
                "the idle thread did not end"
            );
            std::thread::sleep(WRITE_POLL / 4);
        }
    }

    #[test]
    fn frames_arrive_in_the_wire_format_and_a_closed_reader_is_removed() {
        let (ours, mut theirs) = UnixStream::pair().unwrap();
        let mut streams = FrameStreams::default();
        streams
            .open(StreamTarget::Socket(ours.into()), ":1.1")
            .unwrap();
        let mut out = ModeOutput::new(3, 2);
        out.signed_dn.data = vec![-1.0, 0.0, 1.0, 2.5, -7.0, 100.0];
        out.sequence = 9;
        let out = out_frame(out);
        streams.send(&out);
        let mut head = [0u8; HEADER_BYTES];
        theirs.read_exact(&mut head).unwrap();
        let h = FrameHeader::decode(&head).unwrap();
        assert_eq!((h.sequence, h.width, h.height), (9, 3, 2));
        let mut body = vec![0u8; h.body_bytes()];
        theirs.read_exact(&mut body).unwrap();
        let mut dn = [0f32; 6];
        get_f32s(&body, &mut dn);
        assert_eq!(dn.to_vec(), out.output.signed_dn.data);
        drop(theirs);
        // The thread sees the closed reader at its next write, then the
        // frame loop at its next send.
        for _ in 0..200 {
            streams.send(&out);
            if streams.is_empty() {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        panic!("a closed stream stayed open");
    }
}
