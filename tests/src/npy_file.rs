//! `.npy` files the tests get from sdid and sdictl, read with sdi-core's
//! reader (the one `sdictl separate` and `report` use).

use std::io::Read;
use std::path::Path;

/// Shape and data of the float32 `.npy` at `path`; panics when it is not
/// one, or when anything follows the data.
pub fn read_npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let mut file =
        std::fs::File::open(path).unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
    let (shape, data) = sdi_core::npy::read_f32(&mut file)
        .unwrap_or_else(|e| panic!("{} is no float32 .npy: {e}", path.display()));
    let mut rest = Vec::new();
    file.read_to_end(&mut rest).expect("read past the data");
    assert!(
        rest.is_empty(),
        "{}: {} bytes after the data",
        path.display(),
        rest.len()
    );
    (shape, data)
}
