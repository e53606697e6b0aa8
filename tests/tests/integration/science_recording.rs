//! Science on recordings made by a running sdid (simulator backend, the
//! colour chart in every mode, on a private dbus-daemon): `sdictl separate`
//! on the recording equals an M1 computed independently in numpy and is
//! within 3% of the simulator's truth pooled over the frame; `report
//! separation` on the recordings (both sources; LS1 alone and LS2 alone from
//! a two-shot recording) gives the errors of the in-memory simulation.

use std::path::Path;
use std::process::{Command, Output};

use sdi_core::npy::read_f32;
use sdi_tests::dbus::{bin, Bus, Daemon};
use sdi_tests::m1_reference::{numpy_m1_max_rel_diff, numpy_python, recording_to_npy};
use sdi_tests::require_dbus;

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "status {:?}\nstdout: {}\nstderr: {}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Offline `sdictl` (no bus).
fn sdictl(args: &[&str]) -> Output {
    Command::new(bin("sdictl")).args(args).output().unwrap()
}

/// Records `seconds` of the running daemon into `rec`.
fn record(d: &Daemon, rec: &Path, seconds: f64) {
    ok(&d.ctl(&["record", s(rec), "--seconds", &seconds.to_string()]));
}

fn rows(doc: &serde_json::Value) -> Vec<(String, String, f64, f64)> {
    doc["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r["method"].as_str().unwrap().to_owned(),
                r["params"].as_str().unwrap().to_owned(),
                r["rel_rmse_plus"].as_f64().unwrap(),
                r["rel_rmse_minus"].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn separation_on_sdid_recordings_matches_numpy_truth_and_the_simulation() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    let (both, two) = (p("both.sdirec"), p("two-shot.sdirec"));
    {
        let bus = Bus::start();
        // The colour chart in every mode: raw (both sources) and two-shot
        // (LS1 alone, LS2 alone) show the same scene.
        let d = Daemon::start(&bus, &["--scene", "colour-chart"]);
        // 128 dark frames: the dark frame's own noise enters the measured
        // truth per pixel (with 32, pooled M1 read 4.0%/5.5% against 3.6%/4.9%).
        ok(&d.ctl(&["dark-frame", "128"]));
        record(&d, &both, 6.0);
        ok(&d.ctl(&["set-mode", "two-shot"]));
        record(&d, &two, 8.0);
    }

    // 1. sdictl separate on the recording.
    let sep = p("s.npy");
    let out = ok(&sdictl(&[
        "--json",
        "separate",
        "--method",
        "m1",
        "--in",
        s(&both),
        "--out",
        s(&sep),
    ]));
    let summary: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let n = summary["frames_in"].as_u64().unwrap() as usize;
    assert!(n >= 60, "only {n} frames recorded");
    let g = summary["gain_dn_per_electron"].as_f64().unwrap();
    let r = summary["read_variance_dn2"].as_f64().unwrap();
    let (shape, est) = read_f32(std::fs::File::open(&sep).unwrap()).unwrap();
    assert_eq!(shape, [2, 240, 320]);
    assert!(est.iter().all(|v| v.is_finite()));

    // Pooled over the frame, within 3% of the simulator's truth for the
    // same sensor and exposure (a static scene: the truth is one image).
    let (f1, truth) = (p("f1.npy"), p("t.npy"));
    ok(&sdictl(&[
        "sim",
        "--scene",
        "colour-chart",
        "--mode",
        "raw",
        "--frames",
        "1",
        "--exposure-us",
        "2000",
        "--out",
        s(&f1),
        "--truth",
        s(&truth),
    ]));
    let (tshape, tv) = read_f32(std::fs::File::open(&truth).unwrap()).unwrap();
    assert_eq!(tshape, shape);
    let px = 240 * 320;
    for c in 0..2 {
        let t: f64 = tv[c * px..(c + 1) * px].iter().map(|&v| v as f64).sum();
        let e: f64 = est[c * px..(c + 1) * px].iter().map(|&v| v as f64).sum();
        let rel = e / t - 1.0;
        eprintln!(
            "channel {c}: pooled {e:.4e} against truth {t:.4e} ({:+.2}%)",
            100.0 * rel
        );
        assert!(rel.abs() < 0.03, "channel {c}: pooled error {rel}");
    }

    // Per pixel, equal to M1 computed in numpy from the recorded frames.
    let frames = p("frames.npy");
    assert_eq!(recording_to_npy(&both, &frames), n);
    if let Some(py) = numpy_python() {
        let diff = numpy_m1_max_rel_diff(&py, &frames, &sep, g, r);
        eprintln!("numpy M1 against sdictl separate: max relative difference {diff:.2e}");
        assert!(diff < 1e-5, "numpy and sdictl differ by {diff} (relative)");
    }

    // 2. report separation on the recordings against the in-memory simulation.
    let estimators = "m1,m1-pooled,m2,m3-separable";
    let measured = ok(&sdictl(&[
        "--json",
        "report",
        "separation",
        "--in",
        s(&both),
        "--truth-plus",
        s(&two),
        "--truth-minus",
        s(&two),
        "--estimators",
        estimators,
        "--out",
        s(&p("measured")),
    ]));
    // The same report on the in-memory simulation of the recorded scene.
    let simulate = |frames: usize, seed: Option<u64>, estimators: &str, out: &str| {
        let (frames, seed) = (frames.to_string(), seed.map(|s| s.to_string()));
        let mut args = vec![
            "--json",
            "report",
            "separation",
            "--scene",
            "colour-chart",
            "--exposure-us",
            "2000",
            "--frames",
            &frames,
            "--estimators",
            estimators,
        ];
        if let Some(seed) = &seed {
            args.extend(["--seed", seed.as_str()]);
        }
        let out = p(out);
        args.extend(["--out", s(&out)]);
        rows(&serde_json::from_str(ok(&sdictl(&args)).trim()).unwrap())
    };
    let simulated = simulate(n, None, estimators, "simulated");
    let measured = rows(&serde_json::from_str(measured.trim()).unwrap());
    let find = |rows: &[(String, String, f64, f64)], method: &str, params: &str| {
        rows.iter()
            .find(|r| r.0 == method && r.1.starts_with(params))
            .map(|r| (r.2, r.3))
            .unwrap_or_else(|| panic!("no row {method} {params}: {rows:?}"))
    };
    let nn = format!("N={n}");
    // M1 over N frames: one realization each, both within 10% relative
    // (seeds 1-3 in memory spread by 4% for pooled M1).
    for (method, params) in [("M1", nn.as_str()), ("M1 pooled", nn.as_str())] {
        let m = find(&measured, method, params);
        let s = find(&simulated, method, params);
        eprintln!(
            "{method} {params}: recordings {:.2}%/{:.2}%, in memory {:.2}%/{:.2}% (I+/I-)",
            100.0 * m.0,
            100.0 * m.1,
            100.0 * s.0,
            100.0 * s.1
        );
        for (a, b) in [(m.0, s.0), (m.1, s.1)] {
            assert!(
                (a / b - 1.0).abs() < 0.10,
                "{method} {params}: {a} on the recordings against {b} in memory"
            );
        }
    }
    // The single-frame estimators depend on the one frame's noise. M3's
    // error lies within the spread of four in-memory seeds, widened by 10%.
    // M2's is heavy-tailed: its automatic segmentation fails on some frames
    // (16 seeds in memory, smooth r=2, I+: 48-59%, and 113% once), and an
    // sdid recording's first frame is just another draw (80% in 1 of 10
    // runs), so a range of four seeds held it only 9 times in 10; M2 must
    // stay below 3x the seeds' median (a recording that garbled frames
    // would not).
    let seeds: Vec<Vec<(String, String, f64, f64)>> = (1..=4)
        .map(|seed| simulate(2, Some(seed), "m2,m3-separable", &format!("seed{seed}")))
        .collect();
    {
        let m = find(&measured, "M2 auto", "smooth r=2");
        for (c, got) in [(0, m.0), (1, m.1)] {
            let mut vals: Vec<f64> = seeds
                .iter()
                .map(|r| find(r, "M2 auto", "smooth r=2"))
                .map(|v| if c == 0 { v.0 } else { v.1 })
                .collect();
            vals.sort_by(f64::total_cmp);
            let median = 0.5 * (vals[1] + vals[2]);
            eprintln!(
                "M2 auto smooth r=2 {}: recordings {:.2}%, in memory median {:.2}% ({:.2}%..{:.2}%)",
                ["I+", "I-"][c],
                100.0 * got,
                100.0 * median,
                100.0 * vals[0],
                100.0 * vals[3]
            );
            assert!(
                got > 0.0 && got < 3.0 * median,
                "M2 auto smooth r=2: {got} on the recordings, median {median} in memory"
            );
        }
    }
    for (method, params) in [
        ("M3 separable", "sd=1.5 sr=2sigma"),
        ("M3 separable", "sd=1.5 sr=4sigma"),
    ] {
        let m = find(&measured, method, params);
        let spread: Vec<(f64, f64)> = seeds.iter().map(|r| find(r, method, params)).collect();
        for (c, got) in [(0, m.0), (1, m.1)] {
            let vals: Vec<f64> = spread
                .iter()
                .map(|v| if c == 0 { v.0 } else { v.1 })
                .collect();
            let lo = vals.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = vals.iter().cloned().fold(0.0, f64::max);
            eprintln!(
                "{method} {params} {}: recordings {:.2}%, in memory {:.2}%..{:.2}%",
                ["I+", "I-"][c],
                100.0 * got,
                100.0 * lo,
                100.0 * hi
            );
            assert!(
                got > lo / 1.1 && got < hi * 1.1,
                "{method} {params}: {got} on the recordings, {lo}..{hi} in memory"
            );
        }
    }

    // 3. report noise on the same recordings: the 2x intercept ratio.
    let out = ok(&sdictl(&[
        "--json",
        "report",
        "noise",
        "--in",
        s(&both),
        "--two-shot",
        s(&two),
        "--out",
        s(&p("noise")),
    ]));
    let doc: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let ratio = doc["intercept_ratio"].as_f64().unwrap();
    let se = doc["intercept_ratio_se"].as_f64().unwrap();
    eprintln!("report noise on the recordings: ratio {ratio:.3} +- {se:.3}");
    assert!(
        (ratio - 2.0).abs() < (4.0 * se).max(0.02),
        "{ratio} +- {se}"
    );
}

/// `sdictl status` tells the simulator's light-travel warning: the
/// depth-edge scene at the board's 12 MHz, not at the simulator's default
/// 1 MHz, and not for a scene fixed with `sdid --scene` that has no depth.
#[test]
fn status_warns_of_light_travel_where_it_matters() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--mode", "depth-edge", "--modulation-hz", "12e6"]);
    let status = ok(&d.ctl(&["status"]));
    assert!(status.contains("warning: light travel"), "{status}");
    assert!(status.contains("24% of the charge"), "{status}");
    ok(&d.ctl(&["set", "modulation-hz", "1000000"]));
    let status = ok(&d.ctl(&["status"]));
    assert!(!status.contains("light travel"), "{status}");
    drop(d);
    let d = Daemon::start(&bus, &["--mode", "depth-edge", "--scene", "colour-chart"]);
    let status = ok(&d.ctl(&["status"]));
    assert!(status.contains("scene colour-chart"), "{status}");
    assert!(!status.contains("light travel"), "{status}");
}
