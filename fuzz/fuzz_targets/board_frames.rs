//! Fuzz target: the board's bulk stream, from transfers to difference frames
//! (`FrameAssembler`, opt8241/src/frame_assembler.rs; `QuadDecoder`,
//! opt8241/src/raw_quads.rs), with the saturation probe's depth frames
//! (`SaturationProbe`, opt8241/src/saturation_probe.rs) and the phase
//! projection.
//!
//! Input: a small frame geometry and quad combination (quad 0, q0 - q2, or
//! any phase axis), then transfers of any size and content, each ending in
//! a short packet or not, so frames arrive short, long, zero-length, split
//! anywhere, with frame-number bytes in any order, and depth frames
//! (4 bytes a pixel) asked for or not; bulk timeouts in between.
//! Invariant: no panic or abort; a frame handed on has exactly the raw or
//! the depth byte count; a raw one decodes, a depth one gives a mask of
//! one flag per pixel; the probe waits for at most one depth frame at a
//! time; a transfer of the wrong length is a typed `DecodeError`; the
//! assembler holds at most one frame plus one transfer (allocation bound);
//! time is linear in the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdi_core::quad_phase::PhaseAxis;
use sdi_core::Frame;
use sdi_fuzz::{arbitrary, bytes_up_to, Unstructured};
use sdi_opt8241::depth_frame::depth_frame_bytes;
use sdi_opt8241::frame_assembler::{Assembled, FrameAssembler};
use sdi_opt8241::raw_quads::{DecodeError, QuadCombine, QuadDecoder, QuadLayout};
use sdi_opt8241::saturation_probe::{DepthFrame, ProbeWrite, SaturationProbe};

fn run(u: &mut Unstructured) -> arbitrary::Result<()> {
    let layout = QuadLayout {
        width: u.int_in_range(1..=16)?,
        height: u.int_in_range(1..=8)?,
        quads: if u.arbitrary()? { 4 } else { 6 },
    };
    let frame_bytes = layout.frame_bytes();
    let mut decoder = QuadDecoder::new(layout);
    decoder.frame_number_in_first_byte = u.arbitrary()?;
    decoder.combine = match u.int_in_range(0..=2)? {
        0 => QuadCombine::Quad0,
        1 => QuadCombine::Quad0MinusQuad2,
        _ => QuadCombine::Projected(PhaseAxis {
            // any finite angle; the calibration store refuses the rest
            angle_rad: f64::from(u.arbitrary::<i16>()?) * std::f64::consts::PI / 32768.0,
        }),
    };
    let dark_pixels = u.int_in_range(0..=layout.width * layout.height + 1)?;
    let dark_fits = dark_pixels == layout.width * layout.height;
    let dark = decoder.set_dark_dn(Some(vec![1.5; dark_pixels]));
    assert_eq!(dark.is_ok(), dark_fits, "dark frame size check");
    let mut assembler = FrameAssembler::new(frame_bytes, u.arbitrary()?);
    let depth_bytes = depth_frame_bytes(layout.width, layout.height);
    assembler.also_accept(depth_bytes);
    let mut probe = SaturationProbe::new(u.int_in_range(0..=4)?);
    let mut probing = false;
    let mut frame = Frame::new(1, 1);
    while !u.is_empty() {
        let transfer = bytes_up_to(u, 2 * frame_bytes + 8)?;
        let short = u.arbitrary()?;
        if u.ratio(1, 64)? {
            assembler.reset();
        }
        if u.ratio(1, 16)? && probe.on_no_frame() == Some(ProbeWrite::End) {
            probing = false;
        }
        let write = match assembler.push(transfer, short) {
            Assembled::Frame { bytes, .. } if bytes.len() == depth_bytes => {
                let depth = probe
                    .on_depth_frame(&bytes, layout.width, layout.height)
                    .expect("a depth-length frame gives flags");
                let mut saturated = vec![0u8; layout.width * layout.height];
                probe.apply(&mut saturated);
                assert!(saturated.iter().all(|&s| s <= 1), "one flag a pixel");
                match depth {
                    DepthFrame::Expected(w) => w,
                    DepthFrame::Unasked(w) => Some(w),
                }
            }
            Assembled::Frame { bytes, .. } => {
                assert_eq!(bytes.len(), frame_bytes, "a frame of the wrong size");
                decoder
                    .decode(&bytes, &mut frame)
                    .expect("an assembled frame decodes");
                assert_eq!(
                    (frame.width(), frame.height()),
                    (layout.width, layout.height)
                );
                probe.apply(frame.saturated.data.as_mut_slice());
                decoder.phase_sums(&bytes).expect("a whole frame sums");
                probe.on_raw_frame()
            }
            Assembled::Pending | Assembled::Dropped(_) => None,
        };
        match write {
            Some(ProbeWrite::Start) => {
                assert!(!probing, "a second probe while one waits");
                probing = true;
            }
            Some(ProbeWrite::End) => probing = false,
            None => {}
        }
        assert_eq!(
            decoder.phase_sums(transfer).is_ok(),
            transfer.len() == frame_bytes,
            "phase sums only of a whole frame"
        );
        // The decoder alone on whatever the transfer was.
        match decoder.decode(transfer, &mut frame) {
            Ok(()) => assert_eq!(transfer.len(), frame_bytes),
            Err(DecodeError::Length { got, .. }) => assert_eq!(got, transfer.len()),
            Err(e) => panic!("unexpected error {e}"),
        }
    }
    Ok(())
}

fuzz_target!(|data: &[u8]| {
    let _ = run(&mut Unstructured::new(data));
});
