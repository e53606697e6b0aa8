//! Recordings: SIGTERM finalizes them; kill -9 loses at most the frame in
//! flight and replay plays every complete frame; export writes .npy.

use std::time::Duration;

use sdi_daemon::recording::{Record, RecordingReader};
use sdi_tests::dbus::{stats, Bus, Daemon};
use sdi_tests::require_dbus;

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
    let status = d.signal(libc::SIGTERM);
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
    let bytes = std::fs::read(&npy).unwrap();
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let h = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
    assert!(h.contains(&format!("'shape': ({frames}, 240, 320)")), "{h}");
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
    d.signal(libc::SIGKILL);
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
