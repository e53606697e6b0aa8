//! The options added for science on real data, at their extremes:
//! `report noise --in/--two-shot`, `report separation --estimators/--frames`
//! and `--scene-param`. Every case is a clear error (status 2, a message
//! naming the problem) or a finite result; never a panic or NaN.

mod common;
use common::{load, s, scratch, sdictl, sim, stderr, stdout, write_stack as stack};

use std::path::Path;

/// Noise-like frames: a level per pixel plus a deterministic wobble.
fn frames(n: usize, h: usize, w: usize, level: impl Fn(usize) -> f32) -> Vec<f32> {
    let mut x: u64 = 0x1234_5678;
    (0..n * h * w)
        .map(|i| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            level(i % (h * w)) + (x % 13) as f32 - 6.0
        })
        .collect()
}

fn noise(dir: &Path, snap: &Path, two: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "--json",
        "report",
        "noise",
        "--in",
        s(snap),
        "--two-shot",
        s(two),
        "--out",
        s(dir),
    ];
    args.extend_from_slice(extra);
    sdictl(&args)
}

fn no_panic(o: &std::process::Output) {
    let e = stderr(o);
    assert!(!e.contains("panicked"), "{e}");
    assert!(
        o.status.code().is_some_and(|c| c <= 2),
        "{:?}: {e}",
        o.status
    );
}

#[test]
fn noise_report_on_measured_stacks_at_the_extremes() {
    let dir = scratch("science", "noise");
    let (snap, two) = (dir.join("snap.npy"), dir.join("two.npy"));
    let out = dir.join("out");
    // A usable pair of stacks: 16 pixels at 4 levels (3 levels asked).
    stack(&snap, &[40, 4, 4], &frames(40, 4, 4, |i| (i * 50) as f32));
    stack(&two, &[40, 4, 4], &frames(40, 4, 4, |i| (i * 25) as f32));
    let o = noise(&out, &snap, &two, &["--levels", "3"]);
    no_panic(&o);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert!(v["intercept_ratio"].as_f64().unwrap().is_finite());
    assert!(v["source"].as_str().unwrap().contains("recordings"));

    let cases: Vec<(&str, Vec<usize>, Vec<f32>, &str)> = vec![
        (
            "one frame",
            vec![1, 4, 4],
            frames(1, 4, 4, |_| 5.0),
            "at least 2",
        ),
        (
            "1x1",
            vec![10, 1, 1],
            frames(10, 1, 1, |_| 5.0),
            "usable pixels",
        ),
        (
            "2x1",
            vec![10, 1, 2],
            frames(10, 1, 2, |_| 5.0),
            "usable pixels",
        ),
        ("zero light", vec![10, 4, 4], vec![0.0; 160], "intercept"),
        ("nan", vec![10, 4, 4], vec![f32::NAN; 160], "usable pixels"),
        (
            "inf",
            vec![10, 4, 4],
            (0..160)
                .map(|i| if i % 2 == 0 { f32::INFINITY } else { 1.0 })
                .collect(),
            "usable pixels",
        ),
    ];
    for (name, shape, data, why) in cases {
        let bad = dir.join("bad.npy");
        stack(&bad, &shape, &data);
        for (a, b) in [(&bad, &two), (&snap, &bad)] {
            let o = noise(&out, a, b, &[]);
            no_panic(&o);
            assert!(!o.status.success(), "{name}: accepted");
            let e = stderr(&o);
            assert!(
                e.contains(why) || e.contains("differ in size") || e.contains("same intensity"),
                "{name}: {e}"
            );
            assert!(!stdout(&o).contains("NaN"), "{name}");
        }
    }
    // Truncated .npy: a clear error.
    let bytes = std::fs::read(&snap).unwrap();
    let cut = dir.join("cut.npy");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let o = noise(&out, &cut, &two, &[]);
    no_panic(&o);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("truncated"), "{}", stderr(&o));
    // --in without --two-shot is a usage error.
    let o = sdictl(&["report", "noise", "--in", s(&snap), "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(2));
    // A sensor file with gain 0 for an .npy: refused before any work.
    let sensor = dir.join("zero.toml");
    let mut d =
        sdi_core::sensor::SensorDescription::preset(sdi_core::sensor::SensorPreset::TiOpt8241);
    d.demodulation_contrast = 0.0;
    std::fs::write(&sensor, d.to_toml()).unwrap();
    let o = noise(&out, &snap, &two, &["--sensor", s(&sensor)]);
    no_panic(&o);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

#[test]
fn separation_report_estimators_and_frames() {
    let dir = scratch("science", "estimators");
    let out = dir.join("out");
    let o = sdictl(&[
        "--json",
        "report",
        "separation",
        "--scene",
        "flat-field",
        "--frames",
        "2",
        "--estimators",
        "m1,m3-grid",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    let methods: Vec<&str> = v["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["method"].as_str().unwrap())
        .collect();
    assert!(
        methods.iter().all(|m| *m == "M1" || *m == "M3 grid"),
        "{methods:?}"
    );
    assert!(methods.contains(&"M1") && methods.contains(&"M3 grid"));
    assert!(!stdout(&o).contains("NaN"));
    for (args, why) in [
        (vec!["--frames", "1"], "at least 2"),
        (vec!["--frames", "0"], "at least 2"),
        (vec!["--estimators", "m4"], "invalid value"),
        (vec!["--estimators", ""], "value"),
        (vec!["--scene-param", "no_such=1"], "no parameter 'no_such'"),
        (
            vec!["--scene-param", "ls1_electrons_per_us=nan"],
            "finite number",
        ),
        (
            vec!["--scene-param", "ls1_electrons_per_us=-1"],
            "ls1_electrons_per_us",
        ),
        (vec!["--scene-param", "ls1_electrons_per_us"], "key=value"),
    ] {
        let mut a = vec![
            "report",
            "separation",
            "--scene",
            "flat-field",
            "--out",
            s(&out),
        ];
        a.extend_from_slice(&args);
        let o = sdictl(&a);
        no_panic(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(why), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn scene_params_reach_the_simulator() {
    let dir = scratch("science", "scene-param");
    let (a, b) = (dir.join("a.npy"), dir.join("b.npy"));
    for (path, rate) in [(&a, "4"), (&b, "8")] {
        let o = sim(
            "raw",
            1,
            path,
            &[
                "--scene",
                "flat-field",
                "--scene-param",
                &format!("ls1_electrons_per_us={rate}"),
                "--scene-param",
                "ls2_electrons_per_us=0",
            ],
        );
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let mean = |p: &Path| {
        let (_, v) = load(p);
        v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
    };
    let ratio = mean(&b) / mean(&a);
    assert!((ratio - 2.0).abs() < 0.05, "{ratio}");
    let o = sim(
        "raw",
        1,
        &a,
        &["--scene", "depth-edge", "--scene-param", "fan_rpm=3"],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("source_spacing_mm (default 100.0)"),
        "{}",
        stderr(&o)
    );
}
