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
