//! Fuzz target: the calibration file sdid keeps in its state directory
//! (`CalibrationStore::from_toml`, core/src/calibration/store.rs) and the
//! Skellam matrix H each record gives (eq. skellammatrix), and the phase
//! axis each `[[phase]]` record gives (`sdi_core::quad_phase`).
//!
//! Input: the file's text. Invariant: no panic or abort; a bad file or
//! record is a typed `CalibrationError`; an H that is returned is finite and
//! invertible; an axis that is returned is finite, within [-pi, pi]; time
//! and memory linear in the input.
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
    for record in &store.phases {
        if let Ok(axis) = record.axis() {
            assert!(axis.angle_rad.is_finite() && axis.angle_rad.abs() <= std::f64::consts::PI);
        }
    }
    let _ = store.to_toml();
});
