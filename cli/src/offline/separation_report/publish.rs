//! The outputs: separation.tsv, .svg and .json written first, then the
//! table (or the JSON document) printed.

use super::metrics::ordering;
use super::plot::plot;
use super::{Report, Row};
use crate::exit::CliError;
use crate::offline::report_files::ReportFiles;
use crate::stdout::outln;

/// Writes the files, then prints.
pub(super) fn publish(report: Report, files: ReportFiles, json: bool) -> Result<(), CliError> {
    files.write("separation.tsv", tsv(&report.rows).as_bytes())?;
    if files.contains("separation.svg") {
        let mut svg = String::new();
        plot(&mut svg, &report.scene, &report.rows)
            .map_err(|e| CliError::Runtime(e.to_string()))?;
        files.write("separation.svg", svg.as_bytes())?;
    }
    let doc = json_doc(&report);
    if json {
        let text = serde_json::to_string_pretty(&doc)
            .map_err(|e| CliError::Runtime(format!("JSON: {e}")))?;
        files.write("separation.json", text.as_bytes())?;
    }
    let written = files.commit()?;
    if json {
        outln!("{doc}")?;
        return Ok(());
    }
    print_table(&report)?;
    let names: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
    outln!("wrote {}", names.join(", "))?;
    Ok(())
}

fn print_table(r: &Report) -> Result<(), CliError> {
    let (scene, model, w, h, rows) = (&r.scene, &r.model, r.width, r.height, &r.rows);
    outln!("separation report: scene {scene}, {w}x{h}, sensor {model}, dark-frame subtracted")?;
    outln!("truth: {}", r.truth)?;
    if let Some((p, m)) = r.truth_se {
        outln!(
            "the truth's own sampling error (relative RMS standard error): I+ {:.2}%, I- {:.2}%",
            100.0 * p,
            100.0 * m
        )?;
    }
    outln!("relative RMSE per pixel (rmse), per patch mean (patch), M1's sampling floor per pixel (floor)")?;
    outln!(
        "{:<13} {:<22} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>15} {:>10}",
        "method",
        "params",
        "rmse I+",
        "bias I+",
        "rmse I-",
        "bias I-",
        "patch I+",
        "patch I-",
        "floor I+/I-",
        "ms/frame"
    )?;
    let pct = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.2}%", 100.0 * v));
    for r in rows {
        let floor = r.floor.map_or("-".to_string(), |(a, b)| {
            format!("{:.2}/{:.2}%", 100.0 * a, 100.0 * b)
        });
        outln!(
            "{:<13} {:<22} {:>8.2}% {:>+8.2}% {:>8.2}% {:>+8.2}% {:>9} {:>9} {:>15} {:>10.3}",
            r.method,
            r.params,
            100.0 * r.rmse_plus,
            100.0 * r.bias_plus,
            100.0 * r.rmse_minus,
            100.0 * r.bias_minus,
            pct(r.patch_plus),
            pct(r.patch_minus),
            floor,
            r.ms_per_frame
        )?;
    }
    outln!("{}", ordering(rows))?;
    Ok(())
}

/// The report as JSON (separation.json, and stdout with `--json`).
fn json_doc(report: &Report) -> serde_json::Value {
    let rows = &report.rows;
    let order = ordering(rows);
    let rows: Vec<serde_json::Value> = rows
        .iter()
        .map(|r| {
            serde_json::json!({
                "method": r.method,
                "params": r.params,
                "rel_rmse_plus": r.rmse_plus,
                "rel_bias_plus": r.bias_plus,
                "rel_rmse_minus": r.rmse_minus,
                "rel_bias_minus": r.bias_minus,
                "patch_rmse_plus": r.patch_plus,
                "patch_rmse_minus": r.patch_minus,
                "floor_plus": r.floor.map(|f| f.0),
                "floor_minus": r.floor.map(|f| f.1),
                "ms_per_frame": r.ms_per_frame,
            })
        })
        .collect();
    serde_json::json!({
        "scene": report.scene,
        "sensor": report.model,
        "width": report.width,
        "height": report.height,
        "truth": report.truth,
        "truth_rel_se_plus": report.truth_se.map(|t| t.0),
        "truth_rel_se_minus": report.truth_se.map(|t| t.1),
        "ordering": order,
        "rows": rows,
    })
}

fn tsv(rows: &[Row]) -> String {
    let mut s = String::from("method\tparams\trel_rmse_plus\trel_bias_plus\trel_rmse_minus\trel_bias_minus\tpatch_rmse_plus\tpatch_rmse_minus\tfloor_plus\tfloor_minus\tms_per_frame\n");
    let opt = |v: Option<f64>| v.map_or("NA".to_string(), |v| format!("{v:.6}"));
    for r in rows {
        s += &format!(
            "{}\t{}\t{:.6}\t{:.6}\t{:.6}\t{:.6}\t{}\t{}\t{}\t{}\t{:.4}\n",
            r.method,
            r.params,
            r.rmse_plus,
            r.bias_plus,
            r.rmse_minus,
            r.bias_minus,
            opt(r.patch_plus),
            opt(r.patch_minus),
            opt(r.floor.map(|f| f.0)),
            opt(r.floor.map(|f| f.1)),
            r.ms_per_frame
        );
    }
    s
}
