//! Helpers shared by the CLI's end-to-end tests.
//!
//! sdi-tests depends on sdi-cli, so these tests cannot use its `tests/src`;
//! this module is their one copy of the plumbing, and the M1 reference is
//! the same source file as sdi-tests' own.
#![allow(dead_code)] // each test file uses a subset

#[path = "../../../tests/src/m1_reference.rs"]
pub mod m1_reference;
/// The one require-or-skip function, which the M1 reference uses.
#[path = "../../../tests/src/skip.rs"]
pub mod skip;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// An empty scratch directory `PREFIX-NAME` in the target's test tmpdir.
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{prefix}-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A path as the `&str` an argument list takes.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs the built sdictl.
pub fn sdictl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sdictl"))
        .args(args)
        .output()
        .unwrap()
}

/// `sdictl sim --mode MODE --frames N --out OUT` and `extra`.
pub fn sim(mode: &str, frames: usize, out: &Path, extra: &[&str]) -> Output {
    let frames = frames.to_string();
    let mut args = vec!["sim", "--mode", mode, "--frames", &frames, "--out", s(out)];
    args.extend_from_slice(extra);
    sdictl(&args)
}

/// `sdictl separate --method METHOD --in INPUT --out OUT` and `extra`.
pub fn separate(method: &str, input: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "separate",
        "--method",
        method,
        "--in",
        s(input),
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    sdictl(&args)
}

/// Asserts that sdictl succeeded, its stdout and stderr in the message.
pub fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "status {:?}\nstdout: {}\nstderr: {}",
        o.status,
        stdout(o),
        stderr(o)
    );
}

/// Shape and data of an `.npy` stack.
pub fn load(p: &Path) -> (Vec<usize>, Vec<f32>) {
    sdi_core::npy::read_f32(std::fs::File::open(p).unwrap()).unwrap()
}

/// Writes an `.npy` stack of `shape`.
pub fn write_stack(path: &Path, shape: &[usize], data: &[f32]) {
    sdi_core::npy::write_f32(std::fs::File::create(path).unwrap(), shape, data).unwrap();
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A stdout whose reader is already gone: every write gets EPIPE.
pub fn closed_stdout() -> std::process::Stdio {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    writer.into()
}

/// A stdout that is always full: every write gets ENOSPC.
pub fn full_stdout() -> std::process::Stdio {
    std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap()
        .into()
}

/// Runs the built sdictl with the given stdout (stderr captured).
pub fn sdictl_to(args: &[&str], out: std::process::Stdio) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sdictl"))
        .args(args)
        .stdout(out)
        .output()
        .unwrap()
}

/// The names in `dir`, sorted.
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}
