//! Fuzz target: the `.npy` stacks sdictl's offline commands read
//! (`sdi_core::npy_header::read`, core/src/npy_header.rs, and the
//! element decoding of cli/src/offline/frames.rs).
//!
//! Input: the file. Invariant: no panic or abort; a bad header is a typed
//! `NpyHeaderError`; an accepted header has 1..=2^24-pixel frames and a
//! data offset just past what was read; nothing is allocated from the
//! shape (frames are read one at a time into one frame's buffer, at most
//! 2^24 pixels of 8 bytes); time linear in the input.
#![no_main]

use std::io::{Cursor, Read};

use libfuzzer_sys::fuzz_target;
use sdi_core::npy_header;

fuzz_target!(|data: &[u8]| {
    let mut input = Cursor::new(data);
    let Ok(header) = npy_header::read(&mut input) else {
        return;
    };
    assert_eq!(input.position() as usize, header.data_start);
    let pixels = header.width * header.height;
    assert!((1..=1 << 24).contains(&pixels));
    let size = header.dtype.size();
    let mut frame = Vec::new();
    input
        .take((pixels * size) as u64)
        .read_to_end(&mut frame)
        .expect("reading memory");
    for element in frame.chunks_exact(size) {
        let _ = header.dtype.decode(header.big_endian, element);
    }
});
