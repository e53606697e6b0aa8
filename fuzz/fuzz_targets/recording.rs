//! Fuzz target: the recording reader (`RecordingReader`,
//! recording/src/reader.rs and format.rs), both format versions.
//!
//! Input: a recording file. Each input is read twice: as it is (so the
//! checksums reject most of it) and with the header's and every record's
//! CRC-32 recomputed, so the mutations reach the JSON header, the record
//! decoder and zstd behind the checksums.
//! Invariant: no panic or abort; a bad file is a typed `ReadError` or a
//! damaged tail; every frame read has the header's size; memory is bounded
//! by the largest frame record the header's size allows (the reader's
//! stated bound) and time by the input's length and that size.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;
use sdi_recording::format::{record_crc, RECORD_MAGIC};
use sdi_recording::{Record, RecordingReader};

/// The input with its header and record checksums made to match.
fn with_checksums(data: &[u8]) -> Option<Vec<u8>> {
    let mut out = data.to_vec();
    let header_len = u32::from_le_bytes(out.get(8..12)?.try_into().ok()?) as usize;
    let crc_at = 12usize.checked_add(header_len)?;
    let crc = crc32fast::hash(out.get(12..crc_at)?);
    out.get_mut(crc_at..crc_at + 4)?
        .copy_from_slice(&crc.to_le_bytes());
    let mut at = crc_at + 4;
    while let Some(head) = out.get(at..at + 9) {
        if &head[..4] != RECORD_MAGIC {
            break;
        }
        let kind = head[4];
        let len = u32::from_le_bytes([head[5], head[6], head[7], head[8]]) as usize;
        let body = at + 9;
        let Some(payload) = out.get(body..body + len) else {
            break;
        };
        let crc = record_crc(kind, payload);
        let Some(slot) = out.get_mut(body + len..body + len + 4) else {
            break;
        };
        slot.copy_from_slice(&crc.to_le_bytes());
        at = body + len + 4;
    }
    Some(out)
}

fn read_all(data: &[u8]) {
    let Ok(reader) = RecordingReader::new(Cursor::new(data)) else {
        return;
    };
    let (width, height) = (reader.header().sensor.width, reader.header().sensor.height);
    for record in reader {
        match record {
            Record::Frame { frame, .. } => {
                assert_eq!((frame.width(), frame.height()), (width, height));
            }
            Record::Dark { dn, .. } => assert_eq!((dn.width, dn.height), (width, height)),
            Record::End { .. } => {}
        }
    }
}

fuzz_target!(|data: &[u8]| {
    read_all(data);
    if let Some(fixed) = with_checksums(data) {
        read_all(&fixed);
    }
});
