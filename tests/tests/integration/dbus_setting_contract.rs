//! The setting-change contract (docs/dbus.md, "Setting changes") on the
//! host: `SetMode` and `SetExposureUs` return the sequence number of the
//! first frame produced under the new setting. A recording made across the
//! switches shows that every frame from that number on was captured under
//! the new setting and every frame before under the old one, by the mode
//! each frame is labelled with and by what the frame shows (each mode's
//! simulator scene, each exposure's signal level), frame by frame: no frame
//! is guessed to be "late enough".

use sdi_recording::{Record, RecordingReader};
use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::require_dbus;

/// Modes with different simulator scenes, in the order they are set.
const MODES: [&str; 4] = ["raw", "direct-only", "depth-edge", "bipolar-colour"];
/// Frames each setting is held before the next switch.
const HOLD_FRAMES: u64 = 10;
/// Block size of the per-frame signature, pixels.
const BLOCK: usize = 20;

/// `sdictl --json ARGS` -> the announced first sequence number.
fn first_sequence(d: &Daemon, args: &[&str]) -> u64 {
    let mut all = vec!["--json"];
    all.extend_from_slice(args);
    let out = d.ctl(&all);
    assert!(
        out.status.success(),
        "sdictl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    v["first_sequence"]
        .as_u64()
        .unwrap_or_else(|| panic!("no first_sequence in {v}"))
}

/// Holds the current setting for `HOLD_FRAMES` frames after `from`: setting
/// the same mode again returns the next frame's number, so no sleep guesses
/// how long frames take.
fn hold(d: &Daemon, mode: &str, from: u64) {
    while first_sequence(d, &["set-mode", mode]) < from + HOLD_FRAMES {}
}

/// Block means of a frame: a signature that tells scenes and exposures apart
/// far beyond the shot noise of one frame.
fn signature(dn: &[f32], width: usize, height: usize) -> Vec<f64> {
    let (bw, bh) = (width / BLOCK, height / BLOCK);
    let mut sig = vec![0.0; bw * bh];
    for by in 0..bh {
        for bx in 0..bw {
            let mut s = 0.0;
            for y in by * BLOCK..(by + 1) * BLOCK {
                for &v in &dn[y * width + bx * BLOCK..y * width + (bx + 1) * BLOCK] {
                    s += f64::from(v);
                }
            }
            sig[by * bw + bx] = s / (BLOCK * BLOCK) as f64;
        }
    }
    sig
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

fn mean(sigs: &[&Vec<f64>]) -> Vec<f64> {
    let mut m = vec![0.0; sigs[0].len()];
    for s in sigs {
        for (a, b) in m.iter_mut().zip(s.iter()) {
            *a += b / sigs.len() as f64;
        }
    }
    m
}

struct Recorded {
    sequence: u64,
    mode: String,
    signature: Vec<f64>,
}

#[test]
fn setting_changes_announce_their_first_frame() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--mode", MODES[0]]);
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("switch.sdirec");
    let out = d.ctl(&["record", rec.to_str().expect("utf-8 path")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // (first sequence, what the frames from it on must show)
    let mut switches: Vec<(u64, String)> = Vec::new();
    for mode in MODES {
        let s = first_sequence(&d, &["set-mode", mode]);
        if let Some((prev, _)) = switches.last() {
            assert!(s > *prev, "sequence went back: {prev} then {s}");
        }
        switches.push((s, mode.to_owned()));
        hold(&d, mode, s);
    }
    let last = MODES[MODES.len() - 1];
    let s = first_sequence(&d, &["set", "exposure-us", "500"]);
    switches.push((s, format!("{last} at 500 us")));
    hold(&d, last, s);
    assert!(d.ctl(&["stop"]).status.success());

    let mut frames = Vec::new();
    for r in RecordingReader::open(&rec).expect("open recording") {
        if let Record::Frame { mode, frame } = r {
            frames.push(Recorded {
                sequence: frame.sequence,
                mode,
                signature: signature(&frame.dn.data, frame.width(), frame.height()),
            });
        }
    }
    assert!(
        frames.windows(2).all(|w| w[1].sequence > w[0].sequence),
        "recorded sequence numbers are not increasing"
    );

    // Segment k: frames [switch k, switch k+1).
    let segment = |k: usize| -> Vec<&Recorded> {
        let lo = switches[k].0;
        let hi = switches.get(k + 1).map_or(u64::MAX, |s| s.0);
        frames
            .iter()
            .filter(|f| f.sequence >= lo && f.sequence < hi)
            .collect()
    };
    for k in 1..switches.len() {
        let (before, after) = (segment(k - 1), segment(k));
        assert!(
            before.len() as u64 >= HOLD_FRAMES && after.len() as u64 >= HOLD_FRAMES,
            "too few recorded frames around switch {k}: {} and {} (dropped?)",
            before.len(),
            after.len()
        );
        // The label: the mode in force at capture.
        let want_before = MODES[(k - 1).min(MODES.len() - 1)];
        let want_after = MODES[k.min(MODES.len() - 1)];
        for f in &before {
            assert_eq!(
                f.mode, want_before,
                "frame {} before switch {k}",
                f.sequence
            );
        }
        for f in &after {
            assert_eq!(f.mode, want_after, "frame {} after switch {k}", f.sequence);
        }
        // The picture: each frame is nearer the other frames of its own side
        // (centroids from all but the two frames next to the switch).
        let old = mean(
            &before[..before.len() - 2]
                .iter()
                .map(|f| &f.signature)
                .collect::<Vec<_>>(),
        );
        let new = mean(&after[2..].iter().map(|f| &f.signature).collect::<Vec<_>>());
        let gap = distance(&old, &new);
        for f in &before {
            let (d_old, d_new) = (distance(&f.signature, &old), distance(&f.signature, &new));
            assert!(
                d_old < d_new,
                "frame {} (before '{}' from {}) looks like the new setting: {d_old:.2} vs {d_new:.2}",
                f.sequence,
                switches[k].1,
                switches[k].0
            );
        }
        for f in &after {
            let (d_old, d_new) = (distance(&f.signature, &old), distance(&f.signature, &new));
            assert!(
                d_new < d_old,
                "frame {} (from {} on: '{}') looks like the old setting: {d_new:.2} vs {d_old:.2}",
                f.sequence,
                switches[k].0,
                switches[k].1
            );
        }
        eprintln!(
            "switch to '{}' at frame {}: {} frames before, {} after, all on their side (centroid gap {gap:.1} DN)",
            switches[k].1,
            switches[k].0,
            before.len(),
            after.len()
        );
    }
}
