//! sdid inside (an approximation of) the file-system sandbox of
//! `sdid.service`, built by `tests/system/sandbox.sh` in a private mount
//! namespace: read-only system, private /tmp, no homes, /var/lib/sdi
//! writable. The daemon must start and serve there; snapshots and
//! recordings reach the caller's /tmp through descriptors, the path methods
//! work directly in /var/lib/sdi and are refused elsewhere.
//!
//! Needs root (mount namespaces with real mounts); skipped otherwise.

use std::path::Path;
use std::process::Output;

use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::process::repo_root;
use sdi_tests::process::stdout_of;
use sdi_tests::require_dbus;

fn failed(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {stderr}");
    assert!(stderr.contains(needle), "expected {needle}: {stderr}");
}

#[test]
fn sdid_serves_inside_the_unit_sandbox() {
    require_dbus!();
    if !sdi_tests::process::is_root() {
        sdi_tests::skipped!(
            "SKIPPED: needs root for the mount namespace of tests/system/sandbox.sh"
        );
        return;
    }
    let state = tempfile::tempdir().unwrap();
    let user_tmp = tempfile::tempdir_in("/tmp").unwrap();
    // An abstract socket: the sandbox's private /tmp would hide a path.
    let bus = Bus::start_with(&[&format!(
        "--address=unix:abstract=sdi-sandbox-{}",
        std::process::id()
    )]);
    let script = repo_root().join("tests/system/sandbox.sh");
    let d = Daemon::start_wrapped(
        &bus,
        &[
            "unshare",
            "--mount",
            "--propagation",
            "private",
            "sh",
            script.to_str().unwrap(),
            state.path().to_str().unwrap(),
        ],
        &["--mode", "depth-edge"],
    );
    assert_eq!(stdout_of(&d.ctl(&["get", "mode"])).trim(), "depth-edge");

    // Descriptors: into the caller's /tmp, which the daemon cannot see.
    let snap = user_tmp.path().join("snap.png");
    stdout_of(&d.ctl(&["snapshot", snap.to_str().unwrap()]));
    assert!(image::open(&snap).is_ok());
    let rec = user_tmp.path().join("run.sdirec");
    stdout_of(&d.ctl(&["record", rec.to_str().unwrap(), "--seconds", "0.5"]));
    assert!(std::fs::metadata(&rec).unwrap().len() > 0);

    // Paths: below /var/lib/sdi (the StateDirectory) the daemon writes ...
    stdout_of(&d.ctl(&["snapshot", "--by-path", "/var/lib/sdi/state.npy"]));
    stdout_of(&d.ctl(&[
        "record",
        "--by-path",
        "/var/lib/sdi/state.sdirec",
        "--seconds",
        "0.5",
    ]));
    assert!(state.path().join("state.npy").is_file());
    assert!(state.path().join("state.sdirec").is_file());
    // ... its private /tmp is refused, and so is the read-only system
    // (every path outside the state directory, before anything is opened).
    let in_tmp = user_tmp.path().join("by-path.npy");
    failed(
        &d.ctl(&["snapshot", "--by-path", in_tmp.to_str().unwrap()]),
        "PrivateTmp",
    );
    // (/etc, not the checkout: a checkout may itself sit under /tmp.)
    let outside = Path::new("/etc/sdi-sandbox-probe.npy");
    failed(
        &d.ctl(&["snapshot", "--by-path", outside.to_str().unwrap()]),
        "org.sdi.Error.InvalidPath",
    );
    assert!(!outside.exists() && !in_tmp.exists());
    // Still serving.
    stdout_of(&d.ctl(&["set-mode", "raw"]));
}
