//! `sdictl board plan` holds its output: the open sequence for 30 Hz and
//! 12 MHz, and the paper's operating point (60 frames per second, 2000 us,
//! section 4), which a full-frame raw-quad stream cannot leave the board's
//! output port at (docs/hardware.md). A change to the plan shows here as a
//! diff against the golden files, which users diff against TI's SDK.

mod common;
use common::{sdictl, stderr, stdout};

use std::path::Path;

fn golden(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn plan_for_30_hz_and_12_mhz_is_the_golden_one() {
    let o = sdictl(&[
        "--json",
        "board",
        "plan",
        "--frame-rate",
        "30",
        "--modulation-hz",
        "12e6",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let got: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
    let want: serde_json::Value =
        serde_json::from_str(&golden("board_plan_30hz_12mhz.json")).expect("golden json");
    assert_eq!(
        got,
        want,
        "{}",
        serde_json::to_string_pretty(&got).unwrap_or_default()
    );
}

#[test]
fn the_papers_operating_point_is_refused_with_the_range() {
    let o = sdictl(&[
        "--json",
        "board",
        "plan",
        "--frame-rate",
        "60",
        "--exposure-us",
        "2000",
        "--modulation-hz",
        "10e6",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let err: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json error");
    assert_eq!(err["error"], "invalid");
    assert_eq!(
        format!("error: {}\n", err["message"].as_str().unwrap_or_default()),
        golden("board_plan_paper.txt")
    );
    assert_eq!(stderr(&o), golden("board_plan_paper.txt"));
}

#[test]
fn text_plan_lists_every_write_with_address_and_bits() {
    let o = sdictl(&["board", "plan"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(
        text.contains("write  tg_dis                   0x5880 [ 0: 0] = 1"),
        "{text}"
    );
    assert!(text.contains("sleep  10 ms"), "{text}");
    assert!(
        text.contains("write  pix_cnt_max              0x5882 [21: 0] = 400000"),
        "{text}"
    );
}

/// Issue 43 (8): under `--json` every refusal is the JSON error object on
/// stdout, whether sdictl's own check or clap's argument parsing refuses:
/// a bad number, an unknown or misspelt option, a missing value, and the
/// same for other commands.
#[test]
fn every_refusal_under_json_is_the_json_error_object() {
    let refused: &[&[&str]] = &[
        &["board", "plan", "--frame-rate=nan"],
        &["board", "plan", "--frame-rate=inf"],
        &["board", "plan", "--frame-rate", "-30"],
        &["board", "plan", "--exposure-us=0"],
        &["board", "plan", "--modulation-hz=1e99"],
        &["board", "plan", "--frame-rate=fast"],
        &["board", "plan", "--frame-rate"],
        &["board", "plan", "--no-such-option"],
        &["board", "plan", "extra"],
        &["board", "no-such-command"],
        &["board"],
        &["sim", "--frames", "x"],
        &["report", "noise", "--bogus"],
        &["set-mode"],
        &["no-such-command"],
    ];
    for args in refused {
        let mut all = vec!["--json"];
        all.extend_from_slice(args);
        let o = sdictl(&all);
        assert_eq!(o.status.code(), Some(2), "{all:?}: {}", stderr(&o));
        let out = stdout(&o);
        let v: serde_json::Value = serde_json::from_str(&out)
            .unwrap_or_else(|e| panic!("{all:?}: stdout {out:?} is not JSON ({e})"));
        assert_eq!(v["error"], "invalid", "{all:?}: {v}");
        assert!(
            v["message"].as_str().is_some_and(|m| !m.is_empty()),
            "{all:?}: {v}"
        );
        assert!(!stderr(&o).is_empty(), "{all:?}: the text stays on stderr");
    }
    // --json after the subcommand counts too (it is a global flag).
    let o = sdictl(&["board", "plan", "--frame-rate=nan", "--json"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(serde_json::from_str::<serde_json::Value>(&stdout(&o)).is_ok());
    // Without --json nothing goes to stdout; help still prints as text.
    let o = sdictl(&["board", "plan", "--frame-rate=nan"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stdout(&o).is_empty());
    let o = sdictl(&["--json", "board", "plan", "--help"]);
    assert!(o.status.success());
    assert!(stdout(&o).contains("Usage"), "{}", stdout(&o));
}
