//! Helpers the fuzz targets share: reading structure out of libFuzzer's
//! bytes with `arbitrary`'s [`Unstructured`].
#![forbid(unsafe_code)]

pub use libfuzzer_sys::arbitrary::{self, Unstructured};

/// At most `max` bytes from the input (fewer when it runs out).
pub fn bytes_up_to<'a>(u: &mut Unstructured<'a>, max: usize) -> arbitrary::Result<&'a [u8]> {
    let len = u.int_in_range(0..=max)?.min(u.len());
    u.bytes(len)
}
