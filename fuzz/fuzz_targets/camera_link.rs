//! Fuzz target: the camera link protocol (`read`, `read_payload`,
//! `skip_payload`, `write`; camera-link/src/lib.rs), both directions: sdid
//! reads the camera process's replies and the camera process reads sdid's
//! messages through the same `read`.
//!
//! Input: a byte stream on the socket. Invariant: no panic or abort; a bad
//! message is a typed `LinkError`; a frame's payload is at most
//! `MAX_PAYLOAD` bytes and text at most 4096; every message read writes
//! back to the same bytes' meaning (read(write(m)) == m); time linear in the
//! input.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;
use sdi_camera_link::{read, read_payload, skip_payload, write, Message};

/// The link's largest frame payload (camera-link's `MAX_PAYLOAD`).
const MAX_PAYLOAD_BYTES: usize = 64 << 20;

fuzz_target!(|data: &[u8]| {
    let mut socket = Cursor::new(data);
    let mut payload = Vec::new();
    for n in 0.. {
        let Ok(message) = read(&mut socket) else {
            return;
        };
        match message {
            Message::Frame { len, .. } => {
                assert!(len <= MAX_PAYLOAD_BYTES);
                // Readers keep some frames and drop others.
                let kept = if n % 2 == 0 {
                    read_payload(&mut socket, len, &mut payload)
                } else {
                    skip_payload(&mut socket, len)
                };
                if kept.is_err() {
                    return;
                }
            }
            other => {
                let mut bytes = Vec::new();
                write(&mut bytes, &other).expect("writing to memory");
                let back = read(&mut Cursor::new(&bytes)).expect("a written message reads");
                assert_eq!(back, other);
            }
        }
    }
});
