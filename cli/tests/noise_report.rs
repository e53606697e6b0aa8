//! `sdictl report noise` reproduces the paper's 2x ratio of the low-light
//! intercepts (two-shot reads out twice) within its stated uncertainty, for
//! both presets and a user-written sensor file.

use std::path::Path;
use std::process::Command;

#[test]
fn intercept_ratio_is_two_within_its_uncertainty() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("noise-report");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let user = dir.join("user.toml");
    let mut d =
        sdi_core::sensor::SensorDescription::preset(sdi_core::sensor::SensorPreset::TiOpt8241);
    d.model = "user".into();
    d.read_noise_electrons = 30.0;
    d.demodulation_contrast = 0.5;
    std::fs::write(&user, d.to_toml()).unwrap();
    for sensor in ["ti", "pmd", user.to_str().unwrap()] {
        let out = dir.join("out");
        let o = Command::new(env!("CARGO_BIN_EXE_sdictl"))
            .args([
                "report", "noise", "--frames", "40", "--sensor", sensor, "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let text = String::from_utf8_lossy(&o.stdout);
        let last = text.lines().last().unwrap();
        assert!(last.starts_with("low-light intercept ratio"), "{last}");
        let nums: Vec<f64> = last
            .split([':', ' ', '('])
            .filter_map(|w| w.parse().ok())
            .collect();
        let (r, se) = (nums[0], nums[1]);
        assert!(se > 0.0 && se < 0.1, "{sensor}: {last}");
        assert!((r - 2.0).abs() <= 3.0 * se + 1e-3, "{sensor}: {last}");
        assert!(out.join("noise.svg").exists() && out.join("noise.tsv").exists());
    }
}

/// `--json`: the fits and the ratio as one JSON object; the files are
/// written first.
#[test]
fn json_summary() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("noise-report-json");
    let _ = std::fs::remove_dir_all(&dir);
    let o = Command::new(env!("CARGO_BIN_EXE_sdictl"))
        .args([
            "report", "noise", "--frames", "10", "--levels", "4", "--json", "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["frames_per_level"], 10);
    assert_eq!(v["levels"], 4);
    for scheme in ["snapshot", "two_shot"] {
        assert!(v[scheme]["intercept_dn2"].as_f64().is_some(), "{v}");
    }
    assert!(v["intercept_ratio"].as_f64().unwrap() > 0.0);
    assert!(dir.join("noise.svg").exists() && dir.join("noise.tsv").exists());
}
