//! Fuzz target: sensor description files (`SensorDescription::from_toml`,
//! core/src/sensor/description.rs; `--sensor FILE` and `sdid.toml`'s
//! `sensor` through config/src/sensor_spec.rs).
//!
//! Input: the file's text. Invariant: no panic or abort; a bad file is a
//! typed `DescriptionError`; a description that validates gives sensor
//! parameters and a mixing matrix without panicking and writes back as
//! TOML that parses again; time and memory linear in the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdi_core::sensor::description::{mixing_with_adc, SensorDescription};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(description) = SensorDescription::from_toml(text) else {
        return;
    };
    let params = description.params();
    let _ = mixing_with_adc(&params);
    let _ = description.check_modulation_hz(20e6);
    let again = SensorDescription::from_toml(&description.to_toml());
    assert!(
        again.is_ok(),
        "a valid description does not read back: {again:?}"
    );
});
