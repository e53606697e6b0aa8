//! Recordings: SIGTERM finalizes them; kill -9 loses at most the frame in
//! flight and replay plays every complete frame; export writes .npy.

use std::time::Duration;

use nix::sys::signal::Signal;
use sdi_recording::{Record, RecordingReader};
use sdi_tests::dbus::{stats, Bus, Daemon};
use sdi_tests::require_dbus;
use sdi_tests::wait::wait_until;

fn read_all(path: &std::path::Path) -> (usize, bool, Option<String>) {
    let mut r = RecordingReader::open(path).unwrap();
    let mut frames = 0;
    let mut ended = false;
    for rec in r.by_ref() {
        match rec {
            Record::Frame { frame, .. } => {
                assert_eq!((frame.width(), frame.height()), (320, 240));
                frames += 1;
            }
            Record::End { frames: n, .. } => {
                assert_eq!(n as usize, frames);
                ended = true;
            }
            Record::Dark { .. } => {}
        }
    }
    (frames, ended, r.damaged_tail().map(str::to_owned))
}

#[test]
fn sigterm_finalizes_recording() {
    require_dbus!();
    let bus = Bus::start();
    let mut d = Daemon::start(&bus, &["--mode", "depth-edge"]);
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("a.sdirec");
    assert!(d.ctl(&["dark-frame", "4"]).status.success());
    let out = d.ctl(&["record", rec.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::thread::sleep(Duration::from_millis(1500));
    let status = d.signal(Signal::SIGTERM);
    assert!(status.success(), "sdid exit {status:?}");
    let (frames, ended, damaged) = read_all(&rec);
    assert!(ended, "no end record");
    assert!(damaged.is_none(), "{damaged:?}");
    assert!(frames >= 20, "only {frames} frames in 1.5 s at 30 Hz");
    let header = RecordingReader::open(&rec).unwrap().header().clone();
    assert_eq!(header.mode, "depth-edge");
    assert_eq!(header.calibration.dark_frames, 4);
    // Export to .npy.
    let npy = dir.path().join("a.npy");
    let out = sdi_tests::dbus::sdictl(
        &bus.address,
        &["export", rec.to_str().unwrap(), npy.to_str().unwrap()],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (shape, _) = sdi_tests::npy_file::read_npy(&npy);
    assert_eq!(shape, [frames, 240, 320]);
}

#[test]
fn kill_9_loses_at_most_the_frame_in_flight_and_replays() {
    require_dbus!();
    let bus = Bus::start();
    let mut d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("k.sdirec");
    assert!(d.ctl(&["record", rec.to_str().unwrap()]).status.success());
    std::thread::sleep(Duration::from_millis(1500));
    let recorded_before_kill = stats(&d)["frames"].as_u64().unwrap();
    d.signal(Signal::SIGKILL);
    let (frames, ended, _damaged) = read_all(&rec);
    assert!(!ended);
    assert!(frames >= 20, "only {frames} complete frames");
    // Append garbage to simulate a torn record: readers stop there cleanly.
    {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new().append(true).open(&rec).unwrap();
        f.write_all(b"SDIR\x01\xff\xff\x00\x00partial").unwrap();
    }
    let (frames2, _, damaged) = read_all(&rec);
    assert_eq!(frames2, frames);
    assert!(damaged.is_some());
    let _ = recorded_before_kill;
    drop(d);
    // Replay on a fresh bus plays every complete frame (looping).
    let bus2 = Bus::start();
    let r = Daemon::start(&bus2, &["--replay", rec.to_str().unwrap(), "--loop"]);
    let backend = r.ctl(&["get", "backend"]);
    assert_eq!(String::from_utf8_lossy(&backend.stdout).trim(), "replay");
    std::thread::sleep(Duration::from_millis(1500));
    let s = stats(&r);
    assert!(s["frames"].as_u64().unwrap() > frames as u64 / 2, "{s}");
    let snap = dir.path().join("replay.npy");
    assert!(r
        .ctl(&["snapshot", snap.to_str().unwrap()])
        .status
        .success());
}

/// `[recording] max_bytes` stops the recording cleanly: an end record, no
/// file past the limit, `Recording` cleared, `Stats.recording_stopped` set,
/// and the next StopRecording says why (org.sdi.Error.RecordingStopped).
#[test]
fn max_bytes_stops_the_recording_cleanly() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("sdid.toml");
    let max_bytes = 600_000u64;
    std::fs::write(&config, format!("[recording]\nmax_bytes = {max_bytes}\n")).unwrap();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--config", config.to_str().unwrap()]);
    let rec = dir.path().join("m.sdirec");
    let out = d.ctl(&["record", rec.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    wait_until("the recording to stop", Duration::from_secs(30), || {
        let r = d.ctl(&["get", "recording"]);
        String::from_utf8_lossy(&r.stdout).trim().is_empty()
    });
    let s = stats(&d);
    let why = s["recording_stopped"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    assert!(why.contains("max_bytes"), "{s}");
    let len = std::fs::metadata(&rec).unwrap().len();
    assert!(len <= max_bytes, "{len} bytes > {max_bytes}");
    let (frames, ended, damaged) = read_all(&rec);
    assert!(ended, "no end record");
    assert!(damaged.is_none(), "{damaged:?}");
    assert!(frames >= 2, "{frames} frames");
    let stop = d.ctl(&["stop"]);
    assert!(!stop.status.success());
    let err = String::from_utf8_lossy(&stop.stderr);
    assert!(
        err.contains("RecordingStopped") && err.contains("max_bytes"),
        "{err}"
    );
}

/// A recording whose header is out of range is refused by `sdid --replay`
/// with the field named and a non-zero exit, at once (no allocation of the
/// claimed size, no endless wait for a frame).
#[test]
fn replay_refuses_out_of_range_headers() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    for (field, value) in [
        ("\"width\":320", "\"width\":100000"),
        ("\"frame_rate_hz\":30.0", "\"frame_rate_hz\":0.0"),
        ("\"frame_rate_hz\":30.0", "\"frame_rate_hz\":-1.0"),
        ("\"frame_rate_hz\":30.0", "\"frame_rate_hz\":1e-300"),
    ] {
        let mut sensor = sdi_core::sensor::SensorPreset::TiOpt8241.params();
        sensor.frame_rate_hz = 30.0;
        let header = sdi_recording::Header {
            format_version: 2,
            started_unix_s: 1.7e9,
            ..sdi_recording::Header::for_sensor("raw", "sim", sensor)
        };
        let json = serde_json::to_string(&header).unwrap();
        assert!(json.contains(field), "{json}");
        let json = json.replace(field, value);
        let mut bytes = sdi_recording::format::FILE_MAGIC.to_vec();
        bytes.extend_from_slice(&(json.len() as u32).to_le_bytes());
        bytes.extend_from_slice(json.as_bytes());
        bytes.extend_from_slice(&crc32fast::hash(json.as_bytes()).to_le_bytes());
        let path = dir.path().join("bad.sdirec");
        std::fs::write(&path, &bytes).unwrap();
        let out = Daemon::command(&bus, &[], &["--replay", path.to_str().unwrap()])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{value}: {err}");
        assert_ne!(out.status.code(), Some(101), "panicked: {err}");
        let name = value.split('"').nth(1).unwrap();
        assert!(
            err.contains(name) && err.contains("out of range"),
            "{value}: {err}"
        );
    }
}
