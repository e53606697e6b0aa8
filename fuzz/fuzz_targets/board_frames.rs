//! Fuzz target: the board's bulk stream, from transfers to difference frames
//! (`FrameAssembler`, `QuadDecoder`; daemon/src/backend/opt8241/frame.rs).
//!
//! Input: a small frame geometry, then transfers of any size and content,
//! each ending in a short packet or not, so frames arrive short, long,
//! zero-length, split anywhere and with frame-number bytes in any order.
//! Invariant: no panic or abort; a frame handed on has exactly the
//! geometry's byte count and decodes; a transfer of the wrong length is a
//! typed `DecodeError`; the assembler holds at most one frame plus one
//! transfer (allocation bound); time is linear in the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdi_core::Frame;
use sdi_daemon::backend::opt8241::frame::{
    Assembled, DecodeError, FrameAssembler, QuadCombine, QuadDecoder, QuadLayout,
};
use sdi_fuzz::{arbitrary, bytes_up_to, Unstructured};

fn run(u: &mut Unstructured) -> arbitrary::Result<()> {
    let layout = QuadLayout {
        width: u.int_in_range(1..=16)?,
        height: u.int_in_range(1..=8)?,
        quads: if u.arbitrary()? { 4 } else { 6 },
    };
    let frame_bytes = layout.frame_bytes();
    let mut decoder = QuadDecoder::new(layout);
    decoder.frame_number_in_first_byte = u.arbitrary()?;
    if u.arbitrary()? {
        decoder.combine = QuadCombine::Quad0MinusQuad2;
    }
    let dark_pixels = u.int_in_range(0..=layout.width * layout.height + 1)?;
    let dark_fits = dark_pixels == layout.width * layout.height;
    let dark = decoder.set_dark_dn(Some(vec![1.5; dark_pixels]));
    assert_eq!(dark.is_ok(), dark_fits, "dark frame size check");
    let mut assembler = FrameAssembler::new(frame_bytes, u.arbitrary()?);
    let mut frame = Frame::new(1, 1);
    while !u.is_empty() {
        let transfer = bytes_up_to(u, 2 * frame_bytes + 8)?;
        let short = u.arbitrary()?;
        if u.ratio(1, 64)? {
            assembler.reset();
        }
        match assembler.push(transfer, short) {
            Assembled::Frame { bytes, .. } => {
                assert_eq!(bytes.len(), frame_bytes, "a frame of the wrong size");
                decoder
                    .decode(&bytes, &mut frame)
                    .expect("an assembled frame decodes");
                assert_eq!(
                    (frame.width(), frame.height()),
                    (layout.width, layout.height)
                );
            }
            Assembled::Pending | Assembled::Dropped(_) => {}
        }
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
