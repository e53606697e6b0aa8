//! `sdictl separate` end to end: the round trip from simulated data alone
//! (pooled within 3% of the truth, per pixel equal to an independent numpy
//! M1), the same on a recording, and the extremes (tiny frames, one frame,
//! NaN/inf, zero light, saturation, a truncated recording, bad sensor files).

mod common;
use common::m1_reference::{numpy_m1_max_rel_diff, numpy_python, recording_to_npy};
use common::{load, ok, s, scratch, sdictl, separate, sim, write_stack};

use std::path::Path;
use std::process::Output;

use sdi_core::modulation::Illumination;
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::{mixing_with_adc, SensorPreset};
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::{Frame, Image};
use sdi_recording::{Header, RecordingFile};

#[test]
fn m1_round_trip_from_data_alone_matches_truth_and_numpy() {
    let dir = scratch("separate", "round-trip");
    let (f, t, out, sig) = (
        dir.join("f.npy"),
        dir.join("t.npy"),
        dir.join("s.npy"),
        dir.join("sigma.npy"),
    );
    ok(&sim(
        "raw",
        300,
        &f,
        &["--scene", "colour-chart", "--truth", s(&t)],
    ));
    ok(&separate("m1", &f, &out, &["--sigma", s(&sig)]));
    let (ts, tv) = load(&t);
    let (ss, sv) = load(&out);
    let (gs, gv) = load(&sig);
    assert_eq!(ts, vec![2, 240, 320]);
    assert_eq!(ss, ts);
    assert_eq!(gs, ts);
    let n = 240 * 320;
    for c in 0..2 {
        let truth: f64 = tv[c * n..(c + 1) * n].iter().map(|&v| v as f64).sum();
        let est: f64 = sv[c * n..(c + 1) * n].iter().map(|&v| v as f64).sum();
        let rel = est / truth - 1.0;
        assert!(rel.abs() < 0.03, "channel {c}: pooled error {rel}");
    }
    assert!(sv.iter().chain(&gv).all(|v| v.is_finite()));
    // The standard errors predict the per-pixel scatter (within 25%).
    let rms_err = (sv
        .iter()
        .zip(&tv)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum::<f64>()
        / sv.len() as f64)
        .sqrt();
    let rms_se = (gv.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / gv.len() as f64).sqrt();
    assert!(
        (rms_err / rms_se - 1.0).abs() < 0.25,
        "{rms_err} vs {rms_se}"
    );
    let Some(py) = numpy_python() else {
        return;
    };
    let h = mixing_with_adc(&SensorPreset::TiOpt8241.params());
    let d = numpy_m1_max_rel_diff(&py, &f, &out, h.gain_dn_per_electron, h.read_variance_dn2);
    assert!(d < 1e-5, "numpy and sdictl differ by {d} (relative)");
}

fn small_sensor() -> sdi_core::sensor::SensorParams {
    let mut p = SensorPreset::TiOpt8241.params();
    p.width = 48;
    p.height = 36;
    p
}

/// A recording in sdid's format of `n` raw snapshot frames with a dark
/// frame record, written through the format's own file writer (the one
/// sdid's recorder thread uses).
fn make_recording(path: &Path, n: usize) {
    let sensor = small_sensor();
    let mut sim = Simulator::new(SimConfig::new(
        sensor.clone(),
        SceneSpec::from_name("colour-chart").unwrap(),
    ))
    .unwrap();
    let header = Header::for_sensor("raw", "sim", sensor.clone());
    let mut w = RecordingFile::create(path, &header).unwrap();
    let mut frame = Frame::new(sensor.width, sensor.height);
    let mut dark = Image::<f32>::new(sensor.width, sensor.height);
    for _ in 0..16 {
        sim.capture_dark(&mut frame);
        for (d, v) in dark.data.iter_mut().zip(&frame.dn.data) {
            *d += v / 16.0;
        }
    }
    w.encode_dark(16, &dark);
    w.write_encoded().unwrap();
    let light = Illumination::snapshot(sensor.modulation_hz);
    for _ in 0..n {
        sim.capture(&light, &mut frame);
        w.encode_frame("raw", &frame);
        w.write_encoded().unwrap();
    }
    w.finish(n as u64, 0).unwrap();
}

#[test]
fn m1_on_a_recording_equals_numpy_and_survives_truncation() {
    let dir = scratch("separate", "recording");
    let rec = dir.join("r.sdirec");
    make_recording(&rec, 120);
    let out = dir.join("s.npy");
    let o = separate("m1", &rec, &out, &[]);
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("recording's sensor"));
    let (shape, v) = load(&out);
    assert_eq!(shape, vec![2, 36, 48]);
    assert!(v.iter().all(|x| x.is_finite()));
    let frames = dir.join("frames.npy");
    assert_eq!(recording_to_npy(&rec, &frames), 120);
    if let Some(py) = numpy_python() {
        let h = mixing_with_adc(&small_sensor());
        let d = numpy_m1_max_rel_diff(
            &py,
            &frames,
            &out,
            h.gain_dn_per_electron,
            h.read_variance_dn2,
        );
        assert!(d < 1e-5, "numpy and sdictl differ by {d} (relative)");
    }
    // The same frames as .npy give the same result with the same sensor.
    let out2 = dir.join("s2.npy");
    let sensor_file = dir.join("small.toml");
    let mut d = sdi_core::sensor::SensorDescription::preset(SensorPreset::TiOpt8241);
    d.width = 48;
    d.height = 36;
    std::fs::write(&sensor_file, d.to_toml()).unwrap();
    ok(&separate(
        "m1",
        &frames,
        &out2,
        &["--sensor", s(&sensor_file)],
    ));
    let (_, v2) = load(&out2);
    let max = v
        .iter()
        .zip(&v2)
        .map(|(a, b)| (a - b).abs() / a.abs().max(1.0))
        .fold(0.0, f32::max);
    assert!(max < 1e-4, "recording and npy differ by {max}");
    // Truncated mid-record: the intact frames are used, with a warning.
    let bytes = std::fs::read(&rec).unwrap();
    let cut = dir.join("cut.sdirec");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let o = separate("m3", &cut, &out, &[]);
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("damaged record"));
    let (shape, v) = load(&out);
    assert!(shape[0] > 10 && shape[0] < 120 && shape[1..] == [2, 36, 48]);
    assert!(v.iter().all(|x| x.is_finite()));
    // Cut inside the header: a clear error.
    std::fs::write(&cut, &bytes[..20]).unwrap();
    let o = separate("m1", &cut, &out, &[]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn extremes_give_finite_flagged_results_or_clear_errors() {
    let dir = scratch("separate", "extremes");
    let out = dir.join("o.npy");
    let sig = dir.join("sig.npy");
    let fl = dir.join("fl.npy");
    let methods = ["m1", "m1-pooled", "m2", "m3", "ml"];
    let cases: Vec<(&str, Vec<usize>, Vec<f32>)> = vec![
        ("1x1 x 5", vec![5, 1, 1], vec![10.0, 12.0, 9.0, 30.0, 11.0]),
        ("2x1 x 2", vec![2, 1, 2], vec![10.0, -4.0, 12.0, 3.0]),
        ("zero light", vec![4, 3, 5], vec![0.0; 60]),
        ("saturated", vec![4, 3, 5], vec![2047.0; 60]),
        (
            "nan and inf",
            vec![3, 2, 3],
            vec![
                f32::NAN,
                1.0,
                2.0,
                f32::INFINITY,
                5.0,
                6.0, //
                f32::NAN,
                3.0,
                -2.0,
                f32::NEG_INFINITY,
                4.0,
                9.0, //
                f32::NAN,
                0.0,
                1.0,
                7.0,
                5.5,
                6.0,
            ],
        ),
    ];
    for (name, shape, data) in &cases {
        let input = dir.join("in.npy");
        write_stack(&input, shape, data);
        for m in methods {
            let o = separate(m, &input, &out, &["--sigma", s(&sig), "--flags", s(&fl)]);
            ok(&o);
            let (os, ov) = load(&out);
            let (_, sv) = load(&sig);
            let (_, fv) = load(&fl);
            assert!(ov.iter().all(|v| v.is_finite()), "{name} {m}: {ov:?}");
            assert!(sv.iter().all(|v| !v.is_nan()), "{name} {m}: {sv:?}");
            assert_eq!(*os.last().unwrap(), shape[2], "{name} {m}");
            if *name == "nan and inf" {
                assert!(
                    fv.iter().any(|&f| f as u8 & 2 != 0),
                    "{name} {m}: NONFINITE flagged"
                );
            }
        }
    }
    // One frame: M1 refuses clearly; per-frame methods give a flagged result.
    let one = dir.join("one.npy");
    write_stack(&one, &[1, 2, 2], &[1.0, 2.0, 3.0, 4.0]);
    let o = separate("m1", &one, &out, &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("at least 2 frames"));
    assert!(!out.exists() || load(&out).0 != vec![2, 2, 2]);
    for m in ["m2", "m3", "ml"] {
        ok(&separate(m, &one, &out, &[]));
        let (os, ov) = load(&out);
        assert_eq!(os, vec![1, 2, 2, 2]);
        assert!(ov.iter().all(|v| v.is_finite()));
    }
    // Truncated .npy and garbage: clear errors, nothing written.
    let bytes = std::fs::read(&one).unwrap();
    let cut = dir.join("cut.npy");
    std::fs::write(&cut, &bytes[..bytes.len() - 3]).unwrap();
    let gone = dir.join("never.npy");
    for bad in [&cut, &dir.join("missing.npy")] {
        let o = separate("m3", bad, &gone, &[]);
        assert!(!o.status.success());
        assert!(!gone.exists());
    }
    // Bad sensor files.
    let input = dir.join("in.npy");
    write_stack(&input, &[3, 1, 2], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    let base = sdi_core::sensor::SensorDescription::preset(SensorPreset::TiOpt8241);
    for (field, value) in [
        ("demodulation_contrast", 0.0),
        ("demodulation_contrast", 1e-12),
        ("conversion_gain_dn_per_electron", 0.0),
        ("read_noise_electrons", -1.0),
    ] {
        let mut t: toml::Table = toml::from_str(&base.to_toml()).unwrap();
        t.insert(field.into(), toml::Value::Float(value));
        let file = dir.join("bad.toml");
        std::fs::write(&file, toml::to_string(&t).unwrap()).unwrap();
        let sensor = ["--sensor", s(&file)];
        let runs: [&dyn Fn() -> Output; 2] = [&|| separate("m1", &input, &gone, &sensor), &|| {
            sim("raw", 1, &gone, &sensor)
        }];
        for run in runs {
            let o = run();
            assert_eq!(o.status.code(), Some(2), "{field}={value}");
            assert!(
                String::from_utf8_lossy(&o.stderr).contains(field),
                "{field}"
            );
            assert!(!gone.exists());
        }
    }
}

#[test]
fn sim_truth_and_two_shot_frames_have_the_documented_shapes() {
    let dir = scratch("separate", "sim-truth");
    let (f, t, ab) = (dir.join("f.npy"), dir.join("t.npy"), dir.join("ab.npy"));
    ok(&sim(
        "two-shot",
        3,
        &f,
        &[
            "--truth",
            s(&t),
            "--two-shot-frames",
            s(&ab),
            "--sensor",
            "pmd",
        ],
    ));
    assert_eq!(load(&t).0, vec![2, 120, 165]);
    let (abs, abv) = load(&ab);
    assert_eq!(abs, vec![3, 2, 120, 165]);
    // A - B is the two-shot output.
    let (_, fv) = load(&f);
    let n = 120 * 165;
    for k in 0..3 {
        for i in (0..n).step_by(97) {
            let d = abv[k * 2 * n + i] - abv[k * 2 * n + n + i];
            assert!((d - fv[k * n + i]).abs() < 1e-3, "frame {k} pixel {i}");
        }
    }
    // Separation mode writes the separated channels, not the difference.
    ok(&sim("separation", 2, &f, &["--sensor", "pmd"]));
    assert_eq!(load(&f).0, vec![2, 2, 120, 165]);
    // A moving scene has one truth per frame.
    ok(&sim(
        "temporal-gradient",
        2,
        &f,
        &["--truth", s(&t), "--sensor", "pmd"],
    ));
    assert_eq!(load(&t).0, vec![2, 2, 120, 165]);
}

#[test]
fn report_separation_on_measured_frames_uses_ls_only_frames_as_truth() {
    let dir = scratch("separate", "measured");
    let (f, ts, ab) = (dir.join("f.npy"), dir.join("ts.npy"), dir.join("ab.npy"));
    ok(&sim(
        "raw",
        100,
        &f,
        &["--scene", "colour-chart", "--sensor", "pmd"],
    ));
    ok(&sim(
        "two-shot",
        100,
        &ts,
        &[
            "--scene",
            "colour-chart",
            "--two-shot-frames",
            s(&ab),
            "--sensor",
            "pmd",
            "--seed",
            "3",
        ],
    ));
    let (shape, v) = load(&ab);
    let plane = shape[2] * shape[3];
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for k in 0..shape[0] {
        a.extend_from_slice(&v[(2 * k) * plane..(2 * k + 1) * plane]);
        b.extend_from_slice(&v[(2 * k + 1) * plane..(2 * k + 2) * plane]);
    }
    let (pa, pb) = (dir.join("a.npy"), dir.join("b.npy"));
    write_stack(&pa, &[shape[0], shape[2], shape[3]], &a);
    write_stack(&pb, &[shape[0], shape[2], shape[3]], &b);
    let out = dir.join("rep");
    let o = sdictl(&[
        "report",
        "separation",
        "--in",
        s(&f),
        "--truth-plus",
        s(&pa),
        "--truth-minus",
        s(&pb),
        "--sensor",
        "pmd",
        "--out",
        s(&out),
        "--json",
    ]);
    ok(&o);
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("separation.json")).unwrap())
            .unwrap();
    let m1 = &doc["rows"][0];
    assert_eq!(m1["method"], "M1");
    for k in ["rel_bias_plus", "rel_bias_minus"] {
        let b = m1[k].as_f64().unwrap();
        assert!(b.abs() < 0.05, "{k} = {b}");
    }
}

/// Outputs and the input are compared as files, not strings: `--sigma`
/// naming `--out` through `..`, or `--out` naming the input through a
/// symlinked directory, is refused before anything is written. `--json`
/// gives the summary as one JSON object.
#[test]
fn same_file_is_refused_and_json_summary() {
    let dir = scratch("separate", "same-file");
    let input = dir.join("in.npy");
    ok(&sim("raw", 3, &input, &["--sensor", "pmd"]));
    std::fs::create_dir(dir.join("sub")).unwrap();
    std::os::unix::fs::symlink(&dir, dir.join("link")).unwrap();
    let out = dir.join("s.npy");
    for (flag, other) in [
        ("--sigma", dir.join("sub/../s.npy")),
        ("--flags", dir.join("link/s.npy")),
    ] {
        let o = separate("m1", &input, &out, &[flag, s(&other)]);
        assert_eq!(o.status.code(), Some(2), "{flag}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("same file"));
        assert!(!out.exists(), "{flag}");
    }
    let o = separate("m1", &input, &dir.join("link/in.npy"), &[]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(load(&input).0, [3, 120, 165], "the input is untouched");

    let o = separate("m1", &input, &out, &["--json"]);
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["frames_in"], 3);
    assert_eq!(v["outputs"], 1);
    assert_eq!(v["method"], "m1");
    assert_eq!(v["out"], s(&out));
    assert!(v["gain_dn_per_electron"].as_f64().unwrap() > 0.0);
}
