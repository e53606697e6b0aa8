//! Every printing command survives a stdout it cannot write: a closed pipe
//! (`sdictl ... | true`) ends quietly with status 0 after the files are
//! written, a full one (`> /dev/full`) is a clear error with status 1, and
//! neither panics (println! did: "failed printing to stdout", status 101).

mod common;
use common::{closed_stdout, full_stdout, names, s, scratch, sdictl_to, stderr};

use std::path::Path;

/// Runs `args` against a closed and a full stdout; `check` sees the closed run's directory.
fn closed_then_full(dir: &Path, args: &dyn Fn(&Path) -> Vec<String>, check: &dyn Fn(&Path)) {
    for (label, closed) in [("closed", true), ("full", false)] {
        let out = dir.join(label);
        let a = args(&out);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let stdout = if closed {
            closed_stdout()
        } else {
            full_stdout()
        };
        let o = sdictl_to(&a, stdout);
        let err = stderr(&o);
        assert!(!err.contains("panicked"), "{a:?} {label}: {err}");
        if closed {
            assert_eq!(o.status.code(), Some(0), "{a:?} {label}: {err}");
            assert!(!err.contains("error"), "{a:?} {label}: {err}");
            check(&out);
        } else {
            assert_eq!(o.status.code(), Some(1), "{a:?} {label}: {err}");
            assert!(err.contains("cannot write to stdout"), "{a:?}: {err}");
        }
    }
}

fn owned(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

#[test]
fn sim_and_separate() {
    let dir = scratch("stdout", "sim");
    closed_then_full(
        &dir,
        &|out| {
            let mut a = owned(&["sim", "--mode", "raw", "--frames", "3", "--out"]);
            a.push(s(&out.join("f.npy")).into());
            a
        },
        &|out| assert_eq!(names(out), ["f.npy"]),
    );
    let input = dir.join("closed/f.npy");
    closed_then_full(
        &dir.join("sep"),
        &|out| {
            let mut a = owned(&["separate", "--method", "m1", "--in", s(&input), "--out"]);
            a.push(s(&out.join("s.npy")).into());
            a
        },
        &|out| assert_eq!(names(out), ["s.npy"]),
    );
}

#[test]
fn reports_write_their_files_first() {
    let dir = scratch("stdout", "report");
    closed_then_full(
        &dir.join("separation"),
        &|out| {
            let mut a = owned(&["report", "separation", "--scene", "flat-field"]);
            a.extend(owned(&["--max-frames", "10", "--out", s(out)]));
            a
        },
        &|out| assert_eq!(names(out), ["separation.svg", "separation.tsv"]),
    );
    closed_then_full(
        &dir.join("noise"),
        &|out| {
            let mut a = owned(&["report", "noise", "--frames", "3", "--levels", "3"]);
            a.extend(owned(&["--out", s(out)]));
            a
        },
        &|out| assert_eq!(names(out), ["noise.svg", "noise.tsv"]),
    );
}

#[test]
fn completions_and_man() {
    let dir = scratch("stdout", "gen");
    for args in [
        &["completions", "bash"][..],
        &["man"][..],
        &["--json", "completions", "zsh"][..],
    ] {
        closed_then_full(&dir, &|_| owned(args), &|_| {});
    }
}
