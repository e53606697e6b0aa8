//! Fuzz target: `.npy` files (`sdi_core::npy::read_f32`, core/src/npy.rs),
//! as `sdictl` and the tests read them.
//!
//! Input: the file. Invariant: no panic or abort; a bad file is a typed
//! `NpyError`; the data read has exactly the shape's element count; memory
//! is bounded by the input's length (the shape alone allocates nothing) and
//! time is linear in it.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((shape, values)) = sdi_core::npy::read_f32(Cursor::new(data)) {
        assert_eq!(shape.iter().product::<usize>(), values.len());
        assert!(values.len() * 4 <= data.len());
    }
});
