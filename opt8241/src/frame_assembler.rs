//! Frame boundaries in the bulk byte stream: which transfers make a frame.
//!
//! The SDK reads `frame_bytes + 255` per bulk transfer and keeps only
//! transfers of exactly `frame_bytes` (`Voxel/USBBulkStreamer.cpp`). How
//! the firmware terminates a frame is not documented, so the
//! [`FrameAssembler`] also checks the frame number that
//! `debug_frame_number_en` writes into the first byte of every frame, drops
//! frames that are out of sequence and locks on again after two consecutive
//! numbers.

/// What the assembler made of a bulk transfer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Assembled {
    /// A complete, in-sequence frame (its first byte's frame number, if used).
    Frame {
        bytes: Vec<u8>,
        frame_number: Option<u8>,
        /// Frames the board numbered but we never received.
        skipped: u32,
    },
    /// Data kept, frame not complete yet.
    Pending,
    /// A transfer or frame that was thrown away, and why.
    Dropped(DropReason),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropReason {
    /// A frame ended with the wrong byte count (short packet too early, or
    /// data ran past the frame size): the stream was misaligned.
    WrongLength { got: usize },
    /// Frame number out of sequence: misaligned or reordered; waiting to lock on.
    OutOfSequence { expected: u8, got: u8 },
    /// First frame(s) after a loss of lock, used to re-lock.
    Relocking,
}

/// Cuts the bulk byte stream into frames and keeps it aligned.
///
/// Transfers ending in a short packet end a frame. Without frame numbers a
/// frame is accepted when it has exactly `frame_bytes` (as the SDK does);
/// with frame numbers it must also follow the previous one (mod 256; small
/// forward gaps count as skipped frames).
#[derive(Debug)]
pub struct FrameAssembler {
    frame_bytes: usize,
    /// A second frame length taken as a whole frame: the saturation
    /// probe's depth frames ([`crate::depth_frame`]).
    also_bytes: Option<usize>,
    check_numbers: bool,
    buf: Vec<u8>,
    /// Discarding until the next short packet (after an overrun).
    discarding: bool,
    last_number: Option<u8>,
    locked: bool,
    pub stats: AssemblerStats,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AssemblerStats {
    pub frames: u64,
    pub dropped: u64,
    pub misaligned: u64,
    pub resyncs: u64,
    pub skipped: u64,
}

/// Largest forward jump of the frame number still taken as dropped frames
/// rather than misalignment.
pub const MAX_FRAME_NUMBER_GAP: u8 = 8;

impl FrameAssembler {
    pub fn new(frame_bytes: usize, check_numbers: bool) -> Self {
        Self {
            frame_bytes,
            also_bytes: None,
            check_numbers,
            buf: Vec::with_capacity(frame_bytes),
            discarding: false,
            last_number: None,
            locked: !check_numbers,
            stats: AssemblerStats::default(),
        }
    }

    pub fn frame_bytes(&self) -> usize {
        self.frame_bytes
    }

    /// Also accepts frames of `bytes` (smaller than a raw-quad frame), in
    /// the same numbering: the caller tells them apart by length.
    pub fn also_accept(&mut self, bytes: usize) {
        self.also_bytes = Some(bytes);
    }

    /// True while frames are being delivered in sequence.
    pub fn is_locked(&self) -> bool {
        self.locked
    }

    /// Forgets partial data and the sequence (after a halt clear or replug).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.discarding = false;
        self.last_number = None;
        self.locked = !self.check_numbers;
    }

    /// Feeds one completed bulk transfer; `short` is true when it ended in a
    /// short (or zero-length) packet, i.e. at a frame boundary.
    pub fn push(&mut self, data: &[u8], short: bool) -> Assembled {
        if self.discarding {
            if short {
                self.discarding = false;
            }
            return Assembled::Pending;
        }
        self.buf.extend_from_slice(data);
        if self.buf.len() > self.frame_bytes.max(self.also_bytes.unwrap_or(0)) {
            let got = self.buf.len();
            self.buf.clear();
            self.discarding = !short;
            return self.drop_misaligned(DropReason::WrongLength { got });
        }
        if !short {
            return Assembled::Pending;
        }
        let bytes = std::mem::take(&mut self.buf);
        self.buf.reserve(self.frame_bytes);
        if bytes.len() != self.frame_bytes && Some(bytes.len()) != self.also_bytes {
            return self.drop_misaligned(DropReason::WrongLength { got: bytes.len() });
        }
        if !self.check_numbers {
            self.stats.frames += 1;
            return Assembled::Frame {
                bytes,
                frame_number: None,
                skipped: 0,
            };
        }
        let number = bytes[0];
        let previous = self.last_number.replace(number);
        match previous {
            Some(prev) => {
                let gap = number.wrapping_sub(prev);
                if (1..=MAX_FRAME_NUMBER_GAP).contains(&gap) {
                    if !self.locked {
                        // Locking on after a loss (not the first lock) is a resync.
                        if self.stats.frames > 0 {
                            self.stats.resyncs += 1;
                        }
                        self.locked = true;
                    }
                    let skipped = u32::from(gap - 1);
                    self.stats.skipped += u64::from(skipped);
                    self.stats.frames += 1;
                    Assembled::Frame {
                        bytes,
                        frame_number: Some(number),
                        skipped,
                    }
                } else if self.locked {
                    self.locked = false;
                    self.drop_misaligned(DropReason::OutOfSequence {
                        expected: prev.wrapping_add(1),
                        got: number,
                    })
                } else {
                    self.stats.dropped += 1;
                    Assembled::Dropped(DropReason::Relocking)
                }
            }
            None => {
                // The very first frame after start or reset: nothing to check yet.
                self.stats.dropped += 1;
                Assembled::Dropped(DropReason::Relocking)
            }
        }
    }

    fn drop_misaligned(&mut self, reason: DropReason) -> Assembled {
        self.stats.dropped += 1;
        self.stats.misaligned += 1;
        if self.check_numbers {
            self.locked = false;
        }
        Assembled::Dropped(reason)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raw_quads::encode_quads;
    use crate::raw_quads::tests::SMALL;

    fn frame(n: u8) -> Vec<u8> {
        encode_quads(SMALL, &[1.0; 12], Some(n))
    }

    #[test]
    fn assembler_accepts_in_sequence_frames_split_over_transfers() {
        let mut a = FrameAssembler::new(SMALL.frame_bytes(), true);
        assert!(matches!(
            a.push(&frame(1), true),
            Assembled::Dropped(DropReason::Relocking)
        ));
        let f2 = frame(2);
        assert_eq!(a.push(&f2[..64], false), Assembled::Pending);
        match a.push(&f2[64..], true) {
            Assembled::Frame {
                frame_number,
                skipped,
                bytes,
            } => {
                assert_eq!((frame_number, skipped), (Some(2), 0));
                assert_eq!(bytes, f2);
            }
            other => panic!("{other:?}"),
        }
        assert!(a.is_locked());
        // a dropped frame on the board side: gap of 2 -> one skipped
        assert!(matches!(
            a.push(&frame(4), true),
            Assembled::Frame { skipped: 1, .. }
        ));
        // wrap-around 255 -> 0
        let mut b = FrameAssembler::new(SMALL.frame_bytes(), true);
        b.push(&frame(255), true);
        assert!(matches!(b.push(&frame(0), true), Assembled::Frame { .. }));
    }

    #[test]
    fn misaligned_frame_is_detected_and_recovered() {
        let mut a = FrameAssembler::new(SMALL.frame_bytes(), true);
        a.push(&frame(10), true);
        assert!(matches!(a.push(&frame(11), true), Assembled::Frame { .. }));
        // a transfer that starts mid-frame: the board's stream shifted by 7 bytes
        let mut shifted = frame(12)[7..].to_vec();
        shifted.extend_from_slice(&frame(13)[..7]);
        let r = a.push(&shifted, true);
        assert!(
            matches!(
                r,
                Assembled::Dropped(DropReason::OutOfSequence { expected: 12, .. })
            ),
            "{r:?}"
        );
        assert!(!a.is_locked());
        // a short packet too early: wrong length
        assert!(matches!(
            a.push(&frame(14)[..50], true),
            Assembled::Dropped(DropReason::WrongLength { got: 50 })
        ));
        // two in-sequence frames lock on again
        assert!(matches!(a.push(&frame(15), true), Assembled::Dropped(_)));
        assert!(matches!(
            a.push(&frame(16), true),
            Assembled::Frame {
                frame_number: Some(16),
                ..
            }
        ));
        assert!(a.is_locked());
        assert_eq!(a.stats.resyncs, 1);
        assert!(a.stats.misaligned >= 2);
    }

    #[test]
    fn a_second_length_is_a_frame_in_the_same_numbering() {
        let mut a = FrameAssembler::new(SMALL.frame_bytes(), true);
        a.also_accept(48);
        a.push(&frame(1), true);
        let mut depth = vec![0u8; 48];
        depth[0] = 2;
        assert!(matches!(
            a.push(&depth, true),
            Assembled::Frame { ref bytes, frame_number: Some(2), .. } if bytes.len() == 48
        ));
        assert!(matches!(a.push(&frame(3), true), Assembled::Frame { .. }));
        assert!(matches!(
            a.push(&depth[..47], true),
            Assembled::Dropped(DropReason::WrongLength { got: 47 })
        ));
    }

    #[test]
    fn overrun_without_terminator_discards_until_next_boundary() {
        let mut a = FrameAssembler::new(SMALL.frame_bytes(), false);
        let f = frame(0);
        assert_eq!(a.push(&f, false), Assembled::Pending);
        assert!(matches!(
            a.push(&f[..8], false),
            Assembled::Dropped(DropReason::WrongLength { got: 104 })
        ));
        assert_eq!(a.push(&f[8..], true), Assembled::Pending);
        assert!(matches!(a.push(&f, true), Assembled::Frame { .. }));
        assert_eq!(a.stats.frames, 1);
    }
}
