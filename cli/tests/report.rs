//! `sdictl report separation` end to end on the colour chart: the table has
//! every estimator with per-pixel and per-patch errors, the paper's ordering
//! line says it holds, and the TSV and SVG are written; unknown scenes are
//! usage errors.

use std::path::Path;
use std::process::Command;

#[test]
fn separation_report_on_the_colour_chart() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report-separation");
    let _ = std::fs::remove_dir_all(&dir);
    let o = Command::new(env!("CARGO_BIN_EXE_sdictl"))
        .args(["report", "separation", "--scene", "colour-chart"])
        .args(["--max-frames", "300", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    for method in [
        "M1 ",
        "M1 pooled",
        "M2 auto",
        "M3 exact",
        "M3 separable",
        "M3 grid",
    ] {
        assert!(out.contains(method), "{method} missing:\n{out}");
    }
    assert!(out.contains("read:=0") && out.contains("patch I+") && out.contains("floor"));
    let ordering = out.lines().find(|l| l.starts_with("ordering")).unwrap();
    assert!(ordering.ends_with("holds"), "{ordering}");
    let tsv = std::fs::read_to_string(dir.join("separation.tsv")).unwrap();
    assert!(tsv.starts_with("method\tparams\trel_rmse_plus"));
    assert!(tsv.lines().count() > 15);
    let svg = std::fs::read_to_string(dir.join("separation.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("M3 grid"));

    let o = Command::new(env!("CARGO_BIN_EXE_sdictl"))
        .args(["report", "separation", "--scene", "no-such-scene", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("colour-chart"));
}

mod common;
use common::{names, scratch, sdictl, stderr, stdout};

fn report(args: &[&str], out: &Path) -> std::process::Output {
    let mut all = vec!["report", "separation"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", out.to_str().unwrap()]);
    sdictl(&all)
}

/// `--max-frames` outside 2..=100000 is refused at parse time (status 2,
/// nothing written): 0 and 1 ran N = 2 silently, 10^9 aborted allocating
/// 96 GB.
#[test]
fn max_frames_is_bounded() {
    let dir = scratch("report", "bounds");
    let out = dir.join("out");
    for n in ["0", "1", "-1", "100001", "1000000000"] {
        let o = report(&["--max-frames", n], &out);
        assert_eq!(o.status.code(), Some(2), "{n}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("from 2 to 100000"),
            "{n}: {}",
            stderr(&o)
        );
        assert!(!out.exists(), "{n}");
    }
}

/// An unwritable --out fails before anything is computed or printed.
#[test]
fn unwritable_out_fails_first() {
    let dir = scratch("report", "unwritable");
    std::fs::write(dir.join("file"), b"").unwrap();
    let out = dir.join("file/sub");
    let o = report(&["--scene", "flat-field", "--max-frames", "10"], &out);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("file/sub"), "{}", stderr(&o));
    assert_eq!(stdout(&o), "", "nothing computed or printed");
    // An output file name taken by a directory: refused before computing too.
    let out = dir.join("taken");
    std::fs::create_dir_all(out.join("separation.svg")).unwrap();
    let o = report(&["--scene", "flat-field", "--max-frames", "10"], &out);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("separation.svg"), "{}", stderr(&o));
    assert_eq!(stdout(&o), "");
    assert_eq!(names(&out), ["separation.svg"]);
}

/// `--json` prints the report as one JSON document (the same as
/// separation.json) instead of the table.
#[test]
fn json_on_stdout() {
    let dir = scratch("report", "json");
    let out = dir.join("out");
    let o = report(
        &["--scene", "flat-field", "--max-frames", "10", "--json"],
        &out,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let doc: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(doc["scene"], "flat-field");
    assert_eq!(doc["rows"][0]["method"], "M1");
    assert_eq!(doc["rows"][0]["params"], "N=10");
    assert!(doc["ordering"].as_str().unwrap().starts_with("ordering"));
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("separation.json")).unwrap())
            .unwrap();
    assert_eq!(file, doc);
    assert_eq!(
        names(&out),
        ["separation.json", "separation.svg", "separation.tsv"]
    );
    // Without --json: the table, and no JSON file.
    let out = dir.join("text");
    let o = report(&["--scene", "flat-field", "--max-frames", "10"], &out);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).starts_with("separation report"),
        "{}",
        stdout(&o)
    );
    assert_eq!(names(&out), ["separation.svg", "separation.tsv"]);
}

/// The rows of a report by method and params, without the timing.
fn errors(doc: &serde_json::Value) -> Vec<(String, Vec<f64>)> {
    doc["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let e = [
                "rel_rmse_plus",
                "rel_bias_plus",
                "rel_rmse_minus",
                "rel_bias_minus",
            ]
            .iter()
            .map(|k| r[*k].as_f64().unwrap())
            .collect();
            (format!("{} {}", r["method"], r["params"]), e)
        })
        .collect()
}

/// On the moving scene every estimate is measured against the truth of its
/// own frames: the single-frame estimators (on frame 1) and M1 at N = 10 get
/// the same errors however many frames follow them. Against the last
/// frame's truth (before) they changed with --max-frames as the scene moved.
#[test]
fn moving_scene_uses_per_frame_truth() {
    let dir = scratch("report", "moving");
    let run = |n: &str| {
        let o = report(
            &["--scene", "fan-pellets", "--max-frames", n, "--json"],
            &dir.join(n),
        );
        assert!(o.status.success(), "{}", stderr(&o));
        let doc: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        assert!(
            doc["truth"].as_str().unwrap().contains("per frame"),
            "{doc}"
        );
        errors(&doc)
    };
    let (short, long) = (run("10"), run("40"));
    let single = |rows: &[(String, Vec<f64>)]| -> Vec<(String, Vec<f64>)> {
        rows.iter()
            .filter(|(m, _)| m.contains("M2") || m.contains("M3") || m.contains("\"N=10\""))
            .cloned()
            .collect()
    };
    let (a, b) = (single(&short), single(&long));
    assert_eq!(a.len(), 1 + 3 + 12, "{a:?}");
    assert_eq!(a, b);
}
