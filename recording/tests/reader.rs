//! The reader against files of both versions and hostile input: version-1
//! files (as written before integer storage) still read; every header
//! field out of range is refused with a typed error; truncations, bit flips
//! and 100,000 random mutations never panic and never allocate more than a
//! frame's worth.

use std::io::Cursor;

use proptest::prelude::*;
use sdi_core::sensor::SensorPreset;
use sdi_core::{Frame, Image};
use sdi_recording::format::{self, Header};
use sdi_recording::{ReadError, Record, RecordingFile, RecordingReader};

fn header(w: usize, h: usize) -> Header {
    let mut sensor = SensorPreset::TiOpt8241.params();
    sensor.width = w;
    sensor.height = h;
    Header {
        started_unix_s: 1.7e9,
        ..Header::for_sensor("raw", "sim", sensor)
    }
}

fn frame(w: usize, h: usize, seq: u64, scale: f32) -> Frame {
    let mut f = Frame::new(w, h);
    for (i, v) in f.dn.data.iter_mut().enumerate() {
        *v = (((i as u64 * 7919 + seq * 31) % 4001) as f32 - 2000.0) * scale;
    }
    f.saturated.data[0] = 1;
    f.sequence = seq;
    f.timestamp_us = seq * 16_667;
    f
}

fn read_all(bytes: &[u8]) -> Result<(Vec<Record>, Option<String>), ReadError> {
    let mut r = RecordingReader::new(Cursor::new(bytes))?;
    let recs: Vec<Record> = r.by_ref().collect();
    Ok((recs, r.damaged_tail().map(str::to_owned)))
}

/// A version-1 file, laid out as the writer before integer storage did.
fn v1_file(w: usize, h: usize, frames: &[Frame], dark: &Image<f32>) -> Vec<u8> {
    let mut hd = header(w, h);
    hd.format_version = 1;
    let mut out = format::header_bytes(format::FILE_MAGIC_V1, &hd).unwrap();
    let (mut payload, mut rec) = (Vec::new(), Vec::new());
    format::encode_dark(4, dark, &mut payload);
    format::record_bytes(format::KIND_DARK, &payload, &mut rec);
    out.extend_from_slice(&rec);
    for f in frames {
        format::encode_frame_v1("raw", f, &mut payload);
        format::record_bytes(format::KIND_FRAME_V1, &payload, &mut rec);
        out.extend_from_slice(&rec);
    }
    format::encode_end(frames.len() as u64, 0, &mut payload);
    format::record_bytes(format::KIND_END, &payload, &mut rec);
    out.extend_from_slice(&rec);
    out
}

/// A current-version file through the file writer: integral, half-DN and
/// fractional frames.
fn v2_file(dir: &tempfile::TempDir, w: usize, h: usize) -> (Vec<u8>, Vec<Frame>) {
    let path = dir.path().join("r.sdirec");
    let mut rf = RecordingFile::create(&path, &header(w, h)).unwrap();
    let frames = vec![
        frame(w, h, 1, 1.0),
        frame(w, h, 2, 0.5),
        frame(w, h, 3, 0.1),
    ];
    for f in &frames {
        rf.encode_frame("raw", f);
        rf.write_encoded().unwrap();
    }
    rf.finish(3, 0).unwrap();
    (std::fs::read(&path).unwrap(), frames)
}

#[test]
fn version_1_files_still_read() {
    let (w, h) = (12, 9);
    let frames: Vec<Frame> = (1..=3).map(|s| frame(w, h, s, 0.25)).collect();
    let dark = Image {
        width: w,
        height: h,
        data: vec![3.5; w * h],
    };
    let (recs, damaged) = read_all(&v1_file(w, h, &frames, &dark)).unwrap();
    assert_eq!(damaged, None);
    assert_eq!(recs.len(), 5);
    assert_eq!(
        recs[0],
        Record::Dark {
            frames: 4,
            dn: dark
        }
    );
    for (r, f) in recs[1..4].iter().zip(&frames) {
        assert_eq!(
            r,
            &Record::Frame {
                mode: "raw".into(),
                frame: f.clone()
            }
        );
    }
    assert_eq!(
        recs[4],
        Record::End {
            frames: 3,
            dropped: 0
        }
    );
}

#[test]
fn version_2_files_round_trip_bit_exact_and_are_smaller() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (32, 24);
    let (bytes, frames) = v2_file(&dir, w, h);
    let (recs, damaged) = read_all(&bytes).unwrap();
    assert_eq!(damaged, None);
    let got: Vec<&Frame> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Frame { frame, .. } => Some(frame),
            _ => None,
        })
        .collect();
    assert_eq!(got.len(), 3);
    for (g, f) in got.iter().zip(&frames) {
        let bits = |x: &Frame| x.dn.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(g), bits(f));
        assert_eq!(g.saturated, f.saturated);
        assert_eq!((g.sequence, g.timestamp_us), (f.sequence, f.timestamp_us));
    }
    assert_eq!(
        recs.last(),
        Some(&Record::End {
            frames: 3,
            dropped: 0
        })
    );
    let dark = Image::<f32>::new(w, h);
    let v1 = v1_file(w, h, &frames, &dark);
    // integer frames take under half their f32 size (the fractional one keeps f32)
    assert!(bytes.len() < v1.len(), "{} vs {}", bytes.len(), v1.len());
}

fn with_header(h: &Header) -> Vec<u8> {
    format::header_bytes(format::FILE_MAGIC, h).unwrap()
}

#[test]
fn out_of_range_headers_are_refused_with_the_field_named() {
    type Edit = Box<dyn Fn(&mut Header)>;
    let cases: Vec<(&str, Edit)> = vec![
        ("sensor.width", Box::new(|h| h.sensor.width = 100_000)),
        ("sensor.height", Box::new(|h| h.sensor.height = 0)),
        ("frame_rate_hz", Box::new(|h| h.frame_rate_hz = 0.0)),
        ("frame_rate_hz", Box::new(|h| h.frame_rate_hz = -60.0)),
        ("frame_rate_hz", Box::new(|h| h.frame_rate_hz = 1e-300)),
        ("frame_rate_hz", Box::new(|h| h.frame_rate_hz = 1e9)),
        ("exposure_us", Box::new(|h| h.exposure_us = 0.0)),
        ("exposure_us", Box::new(|h| h.exposure_us = 2e6)),
        ("modulation_hz", Box::new(|h| h.modulation_hz = -1.0)),
        ("sensor", Box::new(|h| h.sensor.full_well_electrons = -5.0)),
        ("format_version", Box::new(|h| h.format_version = 9)),
    ];
    for (field, f) in cases {
        let mut h = header(8, 8);
        f(&mut h);
        match RecordingReader::new(Cursor::new(with_header(&h))) {
            Err(ReadError::OutOfRange(e)) => assert_eq!(e.field, field),
            Err(ReadError::BadHeader(_)) if field == "format_version" => {}
            other => panic!("{field}: {:?}", other.map(|r| r.header().clone())),
        }
    }
    assert!(RecordingReader::new(Cursor::new(with_header(&header(8, 8)))).is_ok());
}

#[test]
fn truncations_and_bit_flips_never_panic_and_keep_whole_frames() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, _) = v2_file(&dir, 10, 6);
    let (all, _) = read_all(&bytes).unwrap();
    for cut in 0..bytes.len() {
        if let Ok((recs, _)) = read_all(&bytes[..cut]) {
            // a prefix holds a prefix of the records
            assert!(recs.len() <= all.len());
            assert_eq!(recs[..], all[..recs.len()]);
        }
    }
    for byte in 0..bytes.len() {
        for bit in 0..8 {
            let mut b = bytes.clone();
            b[byte] ^= 1 << bit;
            if let Ok((recs, _)) = read_all(&b) {
                assert!(recs.len() <= all.len());
            }
        }
    }
}

/// A hostile record length is refused before any allocation beyond one
/// frame of the header's size.
#[test]
fn record_lengths_are_bounded_by_the_frame_size() {
    let h = header(4, 4);
    let mut bytes = with_header(&h);
    bytes.extend_from_slice(format::RECORD_MAGIC);
    bytes.push(format::KIND_FRAME);
    bytes.extend_from_slice(&(200u32 << 20).to_le_bytes());
    let (recs, damaged) = read_all(&bytes).unwrap();
    assert!(recs.is_empty());
    assert!(damaged.unwrap().contains("exceeds"));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 100_000, failure_persistence: None, ..ProptestConfig::default() })]
    /// Random edits (overwrite, insert, cut) of a valid small file.
    #[test]
    fn random_mutations_never_panic(
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 1..6),
    ) {
        thread_local! {
            static FILE: Vec<u8> = {
                let dir = tempfile::tempdir().unwrap();
                v2_file(&dir, 6, 4).0
            };
        }
        let mut b = FILE.with(|f| f.clone());
        for (pos, val, op) in edits {
            let i = pos as usize % (b.len() + 1);
            match op {
                0 if i < b.len() => b[i] = val,
                1 => b.insert(i, val),
                _ => b.truncate(i),
            }
        }
        let _ = read_all(&b);
    }
}
