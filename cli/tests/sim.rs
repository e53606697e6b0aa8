//! `sdictl sim` end to end: exit statuses, messages, the .npy contents, the
//! PNG, and that nothing is left behind on error.

mod common;
use common::{load, names, scratch, sdictl, sim, stderr};

#[test]
fn writes_npy_of_n_frames_and_png_of_sensor_size() {
    let dir = scratch("sim", "ok");
    let out = dir.join("f.npy");
    let png = dir.join("sub/f.png");
    let o = sim(
        "raw",
        3,
        &out,
        &[
            "--scene",
            "flat-field",
            "--sensor",
            "pmd",
            "--seed",
            "7",
            "--png",
            png.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let (shape, data) = load(&out);
    assert_eq!(shape, vec![3, 120, 165]);
    // Flat field 4 vs 2 electrons/us, 2000 us, 50/50: I+ - I- = 2000 electrons;
    // PMD g = 0.5 * 0.4 DN/electron -> 400 DN.
    let mean = data.iter().map(|&v| f64::from(v)).sum::<f64>() / data.len() as f64;
    assert!((mean - 400.0).abs() < 2.0, "mean {mean}");
    assert!(data.iter().all(|v| v.is_finite()));
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (165, 120));
    // Positive signal renders red-ish.
    let p = img.get_pixel(80, 60);
    assert!(p[0] > p[2], "{p:?}");
    // No temporary files left.
    assert_eq!(names(&dir).len(), 2, "{:?}", names(&dir));
}

#[test]
fn same_seed_same_frames() {
    let dir = scratch("sim", "seed");
    let run = |name: &str| {
        let out = dir.join(name);
        let o = sim("bipolar-colour", 2, &out, &["--seed", "3"]);
        assert!(o.status.success(), "{}", stderr(&o));
        std::fs::read(out).unwrap()
    };
    assert_eq!(run("a.npy"), run("b.npy"));
}

#[test]
fn two_shot_and_temporal_gradient_run() {
    let dir = scratch("sim", "modes");
    for mode in ["two-shot", "temporal-gradient", "depth-edge-vertical"] {
        let out = dir.join(format!("{mode}.npy"));
        let o = sim(
            mode,
            2,
            &out,
            &["--dark-frames", "0", "--colormap", "grey", "--range", "50"],
        );
        assert!(o.status.success(), "{mode}: {}", stderr(&o));
        let (shape, _) = load(&out);
        assert_eq!(shape, vec![2, 240, 320]);
    }
}

#[test]
fn bad_input_exits_2_with_choices_and_writes_nothing() {
    let dir = scratch("sim", "bad");
    let out = dir.join("x.npy");
    let out = out.to_str().unwrap();
    // Each bad option after `--mode raw --frames 1`.
    let bad_options: [(&[&str], &str); 11] = [
        (&["--sensor", "sony"], "pmd"),
        (&["--exposure-us", "NaN"], "exposure"),
        (&["--exposure-us", "0"], "exposure"),
        (&["--exposure-us", "1e300"], "exposure"),
        (&["--ambient", "-1"], "ambient"),
        (&["--ambient", "inf"], "ambient"),
        (&["--colormap", "jet"], "diverging"),
        (&["--range", "0"], "auto"),
        (&["--range", "NaN"], "auto"),
        (&["--seed", "-1"], "seed"),
        (&["--scene", "moon"], "flat-field"),
    ];
    let mut cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--mode", "nope", "--frames", "1"], "two-shot"),
        (vec!["--mode", "raw", "--frames", "0"], "1 to 10000"),
        (vec!["--mode", "raw", "--frames", "-3"], "1 to 10000"),
        (
            vec!["--mode", "raw", "--frames", "99999999999"],
            "1 to 10000",
        ),
    ];
    cases.extend(bad_options.iter().map(|(option, hint)| {
        (
            [&["--mode", "raw", "--frames", "1"], *option].concat(),
            *hint,
        )
    }));
    for (args, hint) in &cases {
        let mut all = vec!["sim"];
        all.extend_from_slice(args);
        all.extend_from_slice(&["--out", out, "--png", "p.png"]);
        let o = sdictl(&all);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(hint), "{args:?}: {}", stderr(&o));
        assert!(names(&dir).is_empty(), "{args:?} left {:?}", names(&dir));
    }
    // Same file for both outputs.
    let o = sdictl(&[
        "sim", "--mode", "raw", "--frames", "1", "--out", out, "--png", out,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(names(&dir).is_empty());
}

#[test]
fn unwritable_output_fails_without_leftovers() {
    let dir = scratch("sim", "io");
    // The PNG's directory is a file, or the PNG is a directory: nothing written.
    std::fs::write(dir.join("blocker"), b"").unwrap();
    let out = dir.join("f.npy");
    let png = dir.join("blocker/f.png");
    let o = sim("raw", 1, &out, &["--png", png.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("blocker"), "{}", stderr(&o));
    assert_eq!(names(&dir), vec!["blocker".to_string()]);
    std::fs::create_dir(dir.join("png-dir")).unwrap();
    let o = sim(
        "raw",
        1,
        &out,
        &["--png", dir.join("png-dir").to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let mut left = names(&dir);
    left.sort();
    assert_eq!(left, vec!["blocker".to_string(), "png-dir".to_string()]);
    assert!(names(&dir.join("png-dir")).is_empty());
}

/// Two outputs that are one file however spelled (`..`, a symlinked
/// directory) are refused before anything is written: the PNG used to
/// replace the .npy.
#[test]
fn same_file_through_dot_dot_or_symlink_is_refused() {
    let dir = scratch("sim", "same-file");
    std::fs::create_dir(dir.join("sub")).unwrap();
    std::os::unix::fs::symlink(dir.join("sub"), dir.join("link")).unwrap();
    let s = |p: std::path::PathBuf| p.to_str().unwrap().to_owned();
    let out = s(dir.join("f.npy"));
    for (flag, other) in [
        ("--png", s(dir.join("sub/../f.npy"))),
        ("--truth", s(dir.join("./f.npy"))),
        ("--two-shot-frames", s(dir.join("link/../f.npy"))),
    ] {
        let o = sdictl(&[
            "sim", "--mode", "two-shot", "--frames", "2", "--out", &out, flag, &other,
        ]);
        assert_eq!(o.status.code(), Some(2), "{flag}: {}", stderr(&o));
        assert!(stderr(&o).contains("same file"), "{flag}: {}", stderr(&o));
        let mut left = names(&dir);
        left.sort();
        assert_eq!(left, ["link", "sub"], "{flag}");
    }
    let o = sim(
        "raw",
        1,
        &dir.join("sub/f.npy"),
        &["--png", &s(dir.join("link/f.npy"))],
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(names(&dir.join("sub")).is_empty());
}

/// `--json`: the summary is one JSON object on stdout.
#[test]
fn json_summary() {
    let dir = scratch("sim", "json");
    let (out, png) = (dir.join("f.npy"), dir.join("f.png"));
    let o = sdictl(&[
        "--json",
        "sim",
        "--mode",
        "raw",
        "--scene",
        "flat-field",
        "--frames",
        "2",
        "--sensor",
        "pmd",
        "--out",
        out.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["frames"], 2);
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(165), Some(120))
    );
    assert_eq!(v["mode"], "raw");
    assert_eq!(v["scene"], "flat-field");
    assert_eq!(v["out"], out.to_str().unwrap());
    assert_eq!(v["png"], png.to_str().unwrap());
    assert!(v["png_max_abs_dn"].as_f64().unwrap() > 0.0);
    assert!(v["truth"].is_null());
}
