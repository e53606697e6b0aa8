//! The saturation probe: the depth frame sdid interleaves into the
//! raw-quad stream to read the chip's per-pixel saturation flag, when to
//! switch the board to it and back, and the mask its flags give.
//!
//! Why a probe frame: a raw quad is A - B of one differential pixel
//! (eq. pixeleff), so when ambient light fills both wells the quads fall
//! towards 0 and the pixel looks dark, not clipped; the 12-bit rails only
//! catch one well clipping. Raw-quad words carry nothing else (the SDK
//! keeps bits 11:0, `ToFFrameGenerator::_generateToFRawIQFrame`). The
//! depth output ([`crate::depth_frame`]) has a flags nibble whose bit 3 is
//! set when a pixel's A or B node voltage falls below
//! `saturation_threshold` (OPT9221.dml, 0x5C36 [23:12]; the SDK's
//! `DenoiseFilter` and `HDRFilter` drop samples with `flags & 0x08`).
//!
//! A state machine without I/O: sdid's device (`Opt8241::next_frame`,
//! `daemon/src/backend/opt8241/device.rs`) feeds it every frame and
//! performs the writes it asks for. Every [`PROBE_EVERY_FRAMES`] raw-quad
//! frames it asks for `output_mode` = depth; the depth frame's flags
//! become the mask ORed into the `saturated` plane of the raw-quad frames
//! that follow, until the next probe. Depth frames that follow the one
//! asked for, while the write back to raw quads is on its way (a few
//! under load: three control transfers), are expected and cost nothing;
//! any other depth frame (a switch back that did not take, or a device
//! sending only those) asks for the raw quads again and is unusable to the
//! caller. When [`PROBE_MAX_FAILURES`] probes in a row get no depth frame
//! within [`PROBE_WAIT_FRAMES`] frames, it stops probing: saturation then
//! comes from the 12-bit rails alone, and the caller says so once.

use crate::depth_frame::{
    saturated_from_depth, DepthFrameLength, OUTPUT_MODE_DEPTH, OUTPUT_MODE_RAW_QUADS,
};
use crate::registers::{field, Field};

/// Frames between two probes: one frame in this many (plus one) is a
/// depth frame, and a pixel's saturation is at most this many frames old.
pub const PROBE_EVERY_FRAMES: u32 = 30;
/// Raw-quad frames a probe waits for its depth frame before it gives up
/// (the switch may take effect a frame late; a board that ignores it
/// while streaming never sends one).
pub const PROBE_WAIT_FRAMES: u32 = 3;
/// Probes in a row that got no depth frame after which sdid stops probing.
pub const PROBE_MAX_FAILURES: u32 = 3;

/// The write that starts a probe.
pub const PROBE_START: (Field, u32) = (field::OUTPUT_MODE, OUTPUT_MODE_DEPTH);
/// The write that ends it.
pub const PROBE_END: (Field, u32) = (field::OUTPUT_MODE, OUTPUT_MODE_RAW_QUADS);

/// Depth frames expected after the write back to raw quads, before the
/// next raw-quad frame: frames the board sent before the write landed.
pub const DEPTH_FRAMES_AFTER_END: u32 = 16;

/// A register write the probe asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProbeWrite {
    /// `output_mode` = depth: the next frame carries the flags.
    Start,
    /// `output_mode` = raw quads again.
    End,
}

impl ProbeWrite {
    pub fn field_value(self) -> (Field, u32) {
        match self {
            ProbeWrite::Start => PROBE_START,
            ProbeWrite::End => PROBE_END,
        }
    }
}

/// What a depth frame was, and the write it asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthFrame {
    /// The probe's, or one sent before the write back to raw quads landed.
    Expected(Option<ProbeWrite>),
    /// Nobody asked for it: the write back to raw quads again.
    Unasked(ProbeWrite),
}

/// Counters for the stream statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ProbeStats {
    /// Probes started.
    pub probes: u64,
    /// Depth frames whose flags were taken.
    pub depth_frames: u64,
    /// Probes that got no depth frame in time.
    pub missed: u64,
}

#[derive(Debug, Clone)]
pub struct SaturationProbe {
    every_frames: u32,
    since_probe: u32,
    /// Raw-quad frames since the probe started, while it waits.
    waiting: Option<u32>,
    missed_in_a_row: u32,
    gave_up: bool,
    /// Giving up not yet said.
    gave_up_untold: bool,
    /// Depth frames still expected after the write back to raw quads.
    end_grace: u32,
    /// 1 = saturated at the last probe; empty before the first.
    mask: Vec<u8>,
    pub stats: ProbeStats,
}

impl Default for SaturationProbe {
    fn default() -> Self {
        Self::new(PROBE_EVERY_FRAMES)
    }
}

impl SaturationProbe {
    /// A probe every `every_frames` raw-quad frames (0: never).
    pub fn new(every_frames: u32) -> Self {
        Self {
            every_frames,
            since_probe: 0,
            waiting: None,
            missed_in_a_row: 0,
            gave_up: every_frames == 0,
            gave_up_untold: false,
            end_grace: 0,
            mask: Vec::new(),
            stats: ProbeStats::default(),
        }
    }

    /// Forgets the mask and the probe under way (a new connection or
    /// geometry); the next probe comes after `every_frames` frames.
    pub fn reset(&mut self) {
        *self = Self {
            stats: self.stats,
            ..Self::new(self.every_frames)
        };
    }

    /// True once probing stopped because the board sends no depth frames.
    pub fn gave_up(&self) -> bool {
        self.gave_up && self.every_frames != 0
    }

    /// True once, right after probing stopped: the caller says so.
    pub fn take_gave_up_notice(&mut self) -> bool {
        std::mem::take(&mut self.gave_up_untold)
    }

    /// Marks the pixels saturated at the last probe in `saturated`.
    pub fn apply(&self, saturated: &mut [u8]) {
        if self.mask.len() == saturated.len() {
            for (s, m) in saturated.iter_mut().zip(&self.mask) {
                *s |= m;
            }
        }
    }

    /// One frame (or one bulk read timeout) of a probe's wait: `Some` with
    /// the write back to raw quads when the wait is over.
    fn wait_tick(&mut self) -> Option<Option<ProbeWrite>> {
        let waited = self.waiting.as_mut()?;
        *waited += 1;
        if *waited <= PROBE_WAIT_FRAMES {
            return Some(None);
        }
        self.waiting = None;
        self.stats.missed += 1;
        self.missed_in_a_row += 1;
        if self.missed_in_a_row >= PROBE_MAX_FAILURES {
            self.gave_up = true;
            self.gave_up_untold = true;
            self.mask.clear();
        }
        Some(Some(ProbeWrite::End))
    }

    /// A bulk read that timed out: counts towards a probe's wait, so a
    /// board that streams nothing in depth output is sent back to raw quads.
    pub fn on_no_frame(&mut self) -> Option<ProbeWrite> {
        self.wait_tick().flatten()
    }

    /// After each raw-quad frame: the write to make now, if any.
    pub fn on_raw_frame(&mut self) -> Option<ProbeWrite> {
        self.end_grace = 0;
        if let Some(write) = self.wait_tick() {
            return write;
        }
        if self.gave_up {
            return None;
        }
        self.since_probe += 1;
        if self.since_probe < self.every_frames {
            return None;
        }
        self.since_probe = 0;
        self.waiting = Some(0);
        self.stats.probes += 1;
        Some(ProbeWrite::Start)
    }

    /// A depth frame: its flags become the mask. The probe's own frame,
    /// or one expected after it, is [`DepthFrame::Expected`]; any other
    /// is [`DepthFrame::Unasked`]. Both may ask for the write back to raw
    /// quads.
    pub fn on_depth_frame(
        &mut self,
        raw: &[u8],
        width: usize,
        height: usize,
    ) -> Result<DepthFrame, DepthFrameLength> {
        saturated_from_depth(raw, width, height, &mut self.mask)?;
        self.stats.depth_frames += 1;
        if self.waiting.take().is_some() {
            self.missed_in_a_row = 0;
            self.end_grace = DEPTH_FRAMES_AFTER_END;
            return Ok(DepthFrame::Expected(Some(ProbeWrite::End)));
        }
        if self.end_grace > 0 {
            self.end_grace -= 1;
            return Ok(DepthFrame::Expected(None));
        }
        Ok(DepthFrame::Unasked(ProbeWrite::End))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn depth(flags: &[u8]) -> Vec<u8> {
        flags.iter().flat_map(|&f| [0, 0, 0, f << 4]).collect()
    }

    #[test]
    fn one_probe_every_n_frames_and_its_mask_marks_the_frames_after() {
        let mut p = SaturationProbe::new(3);
        assert_eq!(p.on_raw_frame(), None);
        assert_eq!(p.on_raw_frame(), None);
        assert_eq!(p.on_raw_frame(), Some(ProbeWrite::Start));
        let mut sat = vec![0u8, 1, 0, 0];
        p.apply(&mut sat);
        assert_eq!(sat, [0, 1, 0, 0], "no mask before the first depth frame");
        // the switch takes a frame to arrive: one raw frame, then the depth one
        assert_eq!(p.on_raw_frame(), None);
        assert_eq!(
            p.on_depth_frame(&depth(&[8, 0, 0xF, 7]), 2, 2),
            Ok(DepthFrame::Expected(Some(ProbeWrite::End)))
        );
        // frames the board sent before the write back landed: no new write
        assert_eq!(
            p.on_depth_frame(&depth(&[8, 0, 0xF, 7]), 2, 2),
            Ok(DepthFrame::Expected(None))
        );
        let mut sat = vec![0u8; 4];
        p.apply(&mut sat);
        assert_eq!(sat, [1, 0, 1, 0]);
        assert_eq!(p.stats.probes, 1);
        assert_eq!(p.stats.depth_frames, 2);
        for _ in 0..2 {
            assert_eq!(p.on_raw_frame(), None);
        }
        assert_eq!(p.on_raw_frame(), Some(ProbeWrite::Start));
    }

    #[test]
    fn a_board_that_never_sends_a_depth_frame_is_given_up_on() {
        let mut p = SaturationProbe::new(1);
        for _ in 0..PROBE_MAX_FAILURES {
            assert_eq!(p.on_raw_frame(), Some(ProbeWrite::Start));
            for _ in 0..PROBE_WAIT_FRAMES {
                assert_eq!(p.on_raw_frame(), None);
            }
            assert_eq!(p.on_raw_frame(), Some(ProbeWrite::End));
        }
        assert!(p.gave_up());
        assert!(p.take_gave_up_notice());
        assert!(!p.take_gave_up_notice());
        assert_eq!(p.on_raw_frame(), None);
        assert_eq!(p.on_no_frame(), None);
        assert_eq!(p.stats.missed, u64::from(PROBE_MAX_FAILURES));
        // an unasked-for depth frame still sends the board back to raw quads
        assert_eq!(
            p.on_depth_frame(&depth(&[0]), 1, 1),
            Ok(DepthFrame::Unasked(ProbeWrite::End))
        );
    }

    #[test]
    fn only_so_many_depth_frames_are_expected_after_the_probes() {
        let mut p = SaturationProbe::new(1);
        assert_eq!(p.on_raw_frame(), Some(ProbeWrite::Start));
        assert!(matches!(
            p.on_depth_frame(&depth(&[0]), 1, 1),
            Ok(DepthFrame::Expected(Some(_)))
        ));
        for _ in 0..DEPTH_FRAMES_AFTER_END {
            assert_eq!(
                p.on_depth_frame(&depth(&[0]), 1, 1),
                Ok(DepthFrame::Expected(None))
            );
        }
        assert!(matches!(
            p.on_depth_frame(&depth(&[0]), 1, 1),
            Ok(DepthFrame::Unasked(_))
        ));
        // a raw-quad frame ends the grace
        assert_eq!(p.on_raw_frame(), Some(ProbeWrite::Start));
        assert_eq!(p.on_raw_frame(), None);
    }

    #[test]
    fn a_board_silent_in_depth_output_is_sent_back_to_raw_quads() {
        let mut p = SaturationProbe::new(1);
        assert_eq!(p.on_raw_frame(), Some(ProbeWrite::Start));
        for _ in 0..PROBE_WAIT_FRAMES {
            assert_eq!(p.on_no_frame(), None);
        }
        assert_eq!(p.on_no_frame(), Some(ProbeWrite::End));
        assert_eq!(p.on_no_frame(), None, "nothing to wait for");
    }

    #[test]
    fn a_probe_switches_output_mode_to_depth_and_back() {
        assert_eq!(PROBE_START.0.name, "output_mode");
        assert_eq!(PROBE_END.1, 15);
    }

    #[test]
    fn a_depth_frame_of_the_wrong_size_is_a_typed_error() {
        let mut p = SaturationProbe::new(1);
        assert!(p.on_depth_frame(&[0u8; 7], 1, 2).is_err());
        assert!(SaturationProbe::new(0).on_raw_frame().is_none());
    }
}
