//! The frame clock never holds a call: at 0.1 fps a setting change returns
//! at once (its first frame is captured at once), and going back to 60 fps
//! takes effect at once. Stats follow reality: the frame rate reads 0 and
//! the device unavailable once a replay has ended.

use std::time::{Duration, Instant};

use sdi_tests::dbus::{stats, Bus, Daemon};
use sdi_tests::require_dbus;

/// Runs `sdictl args`, asserts success and returns how long it took.
fn timed(d: &Daemon, args: &[&str]) -> Duration {
    let t0 = Instant::now();
    let out = d.ctl(args);
    let took = t0.elapsed();
    assert!(
        out.status.success(),
        "sdictl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    took
}

#[test]
fn calls_do_not_wait_on_a_slow_frame_clock() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let to_slow = timed(&d, &["set", "frame-rate", "0.1"]);
    // The frame clock now ticks every 10 s; each call must still return at once.
    let mut worst = to_slow;
    for mode in ["depth-edge", "raw", "bipolar-colour"] {
        worst = worst.max(timed(&d, &["set-mode", mode]));
    }
    worst = worst.max(timed(&d, &["set", "colormap", "grey"]));
    let dir = tempfile::tempdir().unwrap();
    let snap = dir.path().join("s.npy");
    worst = worst.max(timed(&d, &["snapshot", snap.to_str().unwrap()]));
    eprintln!("slowest call at 0.1 fps: {worst:?}");
    assert!(
        worst < Duration::from_secs(2),
        "a call took {worst:?} at 0.1 fps"
    );
    // Back to 60 fps: at once, and frames come at 60 fps right away.
    let to_fast = timed(&d, &["set", "frame-rate", "60"]);
    assert!(
        to_fast < Duration::from_secs(2),
        "back to 60 fps took {to_fast:?}"
    );
    let f0 = stats(&d)["frames"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let f1 = stats(&d)["frames"].as_u64().unwrap();
    eprintln!("frames in 1.5 s after returning to 60 fps: {}", f1 - f0);
    assert!(f1 - f0 >= 45, "{} frames in 1.5 s at 60 fps", f1 - f0);
}

#[test]
fn stats_go_to_zero_when_a_replay_ends() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("short.sdirec");
    sdi_tests::dbus::record_sim(&rec, 0.5);
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--replay", rec.to_str().unwrap()]);
    // The recording lasts about 0.5 s; after it, no frames.
    let t0 = Instant::now();
    loop {
        let s = stats(&d);
        let ended = s["fps"].as_f64() == Some(0.0)
            && s["device_available"].as_bool() == Some(false)
            && s["frames"].as_u64().unwrap_or(0) > 0;
        if ended {
            eprintln!("{s}");
            assert!(
                s["device_state"]
                    .as_str()
                    .unwrap_or_default()
                    .contains("end of recording"),
                "{s}"
            );
            assert!(s["last_frame_age_s"].as_f64().unwrap_or(-1.0) >= 0.0, "{s}");
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "stats still say {s}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}
