//! Fuzz target: `sdid.toml` (`Config::parse` and `Config::validate`,
//! config/src/lib.rs, file.rs, validate.rs).
//!
//! Input: the file's text. Invariant: no panic or abort; a bad file is a
//! typed `toml::de::Error` or `Invalid` naming the key; a file that
//! validates validates again unchanged (adjustments are idempotent); time
//! and memory linear in the input (the `toml` crate's parser).
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdi_config::Config;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(mut config) = Config::parse(text) else {
        return;
    };
    if config.validate().is_ok() {
        let once = format!("{config:?}");
        assert!(
            config.validate().is_ok(),
            "a valid configuration became invalid"
        );
        assert_eq!(once, format!("{config:?}"), "validation is not idempotent");
    }
});
