//! Frame streams (`StreamFrames`): every mode output written into a pipe or
//! socket a client passed, in `sdi_api::frame_stream`'s format, each stream
//! behind a two-slot queue on a thread of its own, so a slow or stalled
//! reader loses frames and the frame loop never waits.

use std::fs::File;
use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;

use sdi_api::frame_stream::{put_f32s, FrameHeader, WireError};
use sdi_core::display::{DisplayMap, DisplayRange};
use sdi_core::mode::{ModeId, ModeOutput};

/// Streams open at once; one more is refused.
pub const MAX_STREAMS: usize = 4;

/// Why a stream was not opened.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    #[error("{MAX_STREAMS} frame streams are open already")]
    TooMany,
    #[error("starting the stream's thread: {0}")]
    Thread(#[source] std::io::Error),
}

/// Why a stream ended (logged at debug level: a client closing is normal).
#[derive(Debug, thiserror::Error)]
enum WriteError {
    #[error("writing to the client: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Wire(#[from] WireError),
}

struct Packet {
    output: Arc<ModeOutput>,
    display: DisplayMap,
    mode: ModeId,
}

struct Stream {
    tx: SyncSender<Packet>,
    dropped: Arc<AtomicU64>,
}

/// The open streams, held by the frame loop.
#[derive(Default)]
pub struct FrameStreams {
    streams: Vec<Stream>,
}

impl FrameStreams {
    /// Starts writing frames into `file`.
    pub fn open(&mut self, file: File) -> Result<(), StreamError> {
        if self.streams.len() >= MAX_STREAMS {
            return Err(StreamError::TooMany);
        }
        let (tx, rx) = sync_channel(2);
        let dropped = Arc::new(AtomicU64::new(0));
        let seen = dropped.clone();
        std::thread::Builder::new()
            .name("sdid-stream".into())
            .spawn(move || {
                if let Err(e) = write_frames(file, &rx, &seen) {
                    tracing::debug!("frame stream ended: {e}");
                }
            })
            .map_err(StreamError::Thread)?;
        self.streams.push(Stream { tx, dropped });
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.streams.len()
    }

    pub fn is_empty(&self) -> bool {
        self.streams.is_empty()
    }

    /// Queues `output` on every stream; never blocks. A full queue drops the
    /// frame (counted in the stream's headers), a closed stream is removed.
    pub fn send(&mut self, output: &Arc<ModeOutput>, display: DisplayMap, mode: ModeId) {
        self.streams.retain(|s| {
            let packet = Packet {
                output: output.clone(),
                display,
                mode,
            };
            match s.tx.try_send(packet) {
                Ok(()) => true,
                Err(TrySendError::Full(_)) => {
                    s.dropped.fetch_add(1, Ordering::Relaxed);
                    true
                }
                Err(TrySendError::Disconnected(_)) => false,
            }
        });
    }
}

/// The stream's thread: encodes and writes until the reader goes away.
fn write_frames(
    mut file: File,
    rx: &Receiver<Packet>,
    dropped: &AtomicU64,
) -> Result<(), WriteError> {
    let mut body = Vec::new();
    while let Ok(p) = rx.recv() {
        let out = &p.output;
        let img = &out.signed_dn;
        let header = FrameHeader {
            sequence: out.sequence,
            timestamp_us: out.timestamp_us,
            width: img.width as u32,
            height: img.height as u32,
            max_abs_dn: match p.display.range {
                DisplayRange::SymmetricAuto => 0.0,
                DisplayRange::Fixed { max_abs_dn } => max_abs_dn,
            },
            dropped: dropped.load(Ordering::Relaxed),
            mode: p.mode.name().to_owned(),
            colormap: p.display.colormap.name().to_owned(),
            has_channels: out.channels.is_some(),
        };
        body.clear();
        body.extend_from_slice(&header.encode()?);
        put_f32s(&mut body, &img.data);
        body.extend_from_slice(&out.flags.data);
        if let Some(ch) = &out.channels {
            put_f32s(&mut body, &ch.i_plus_electrons.data);
            put_f32s(&mut body, &ch.i_minus_electrons.data);
            put_f32s(&mut body, &ch.i_plus_se_electrons.data);
            put_f32s(&mut body, &ch.i_minus_se_electrons.data);
        }
        file.write_all(&body)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_api::frame_stream::{get_f32s, HEADER_BYTES};
    use std::io::Read;
    use std::os::unix::net::UnixStream;

    #[test]
    fn frames_arrive_in_the_wire_format_and_a_closed_reader_is_removed() {
        let (ours, mut theirs) = UnixStream::pair().unwrap();
        let mut streams = FrameStreams::default();
        streams
            .open(File::from(std::os::fd::OwnedFd::from(ours)))
            .unwrap();
        let mut out = ModeOutput::new(3, 2);
        out.signed_dn.data = vec![-1.0, 0.0, 1.0, 2.5, -7.0, 100.0];
        out.sequence = 9;
        let out = Arc::new(out);
        streams.send(&out, DisplayMap::default(), ModeId::DirectOnly);
        let mut head = [0u8; HEADER_BYTES];
        theirs.read_exact(&mut head).unwrap();
        let h = FrameHeader::decode(&head).unwrap();
        assert_eq!((h.sequence, h.width, h.height), (9, 3, 2));
        let mut body = vec![0u8; h.body_bytes()];
        theirs.read_exact(&mut body).unwrap();
        let mut dn = [0f32; 6];
        get_f32s(&body, &mut dn);
        assert_eq!(dn.to_vec(), out.signed_dn.data);
        drop(theirs);
        // The thread sees the closed reader at its next write, then the
        // frame loop at its next send.
        for _ in 0..200 {
            streams.send(&out, DisplayMap::default(), ModeId::DirectOnly);
            if streams.is_empty() {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        panic!("a closed stream stayed open");
    }
}
