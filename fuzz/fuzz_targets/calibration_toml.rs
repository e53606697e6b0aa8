//! Fuzz target: the calibration file sdid keeps in its state directory
//! (`CalibrationStore::from_toml`, core/src/calibration/store.rs) and the
//! Skellam matrix H each record gives (eq. skellammatrix).
//!
//! Input: the file's text. Invariant: no panic or abort; a bad file or
//! record is a typed `CalibrationError`; an H that is returned is finite and
//! invertible; time and memory linear in the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdi_core::calibration::CalibrationStore;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(store) = CalibrationStore::from_toml(text) else {
        return;
    };
    for record in &store.sensors {
        let _ = store.skellam(&record.model, &record.serial);
    }
    let _ = store.to_toml();
});
