//! The path methods (`Snapshot(s)`, `StartRecording(s)`) create only a new
//! plain name in the daemon's state directory; every other path gets one
//! and the same `InvalidPath` (no existence oracle), and a client string
//! never splits a log line.

use std::path::Path;
use std::process::Stdio;

use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::process::stdout_of;
use sdi_tests::require_dbus;

/// Calls `method(path)` and returns the D-Bus error (name, message), or None.
async fn call(address: &str, method: &str, path: &str) -> Option<(String, String)> {
    let (_conn, proxy) = sdi_tests::dbus::raw_camera_proxy(address).await;
    let r = if method == "StopRecording" {
        proxy.call_method(method, &()).await.map(|_| ())
    } else {
        proxy.call_method(method, &(path,)).await.map(|_| ())
    };
    match r {
        Ok(()) => None,
        Err(zbus::Error::MethodError(name, msg, _)) => {
            Some((name.as_str().to_owned(), msg.unwrap_or_default()))
        }
        Err(e) => Some(("other".into(), e.to_string())),
    }
}

fn block_on<T>(f: impl std::future::Future<Output = T>) -> T {
    sdi_tests::dbus::runtime().block_on(f)
}

#[test]
fn every_refused_path_gets_the_same_error() {
    require_dbus!();
    let state = tempfile::tempdir().unwrap();
    let other = tempfile::tempdir().unwrap();
    std::fs::write(other.path().join("exists.npy"), b"x").unwrap();
    std::fs::write(state.path().join("taken.npy"), b"x").unwrap();
    let ro = other.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o500)).unwrap();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--state-dir", state.path().to_str().unwrap()]);
    let s = |n: &str| format!("{}/{n}", state.path().display());
    let o = |n: &str| format!("{}/{n}", other.path().display());
    let probes = [
        o("exists.npy"),          // exists
        o("missing.npy"),         // no such file, parent exists
        o("no-dir/x.npy"),        // no such directory
        o("ro/x.npy"),            // directory not writable
        "/etc/passwd.npy".into(), // root's directory
        s("taken.npy"),           // exists in the state directory
        s("sub/x.npy"),           // below the state directory
        s("x.npy/"),              // trailing slash (was Failed, not InvalidPath)
        "/tmp/new.png/".into(),
        s("../x.npy"),
    ];
    let mut messages = Vec::new();
    for p in &probes {
        let (name, msg) = block_on(call(&d.address, "Snapshot", p)).expect("refused");
        assert_eq!(name, "org.sdi.Error.InvalidPath", "{p}: {msg}");
        messages.push(msg.replacen(p.as_str(), "PATH", 1));
    }
    for (p, m) in probes.iter().zip(&messages) {
        assert_eq!(m, &messages[0], "{p} is told apart from {}", probes[0]);
    }
    let (name, msg) =
        block_on(call(&d.address, "StartRecording", &o("run.sdirec"))).expect("refused");
    assert_eq!(name, "org.sdi.Error.InvalidPath", "{msg}");
    // Nothing was created anywhere, and the taken file is untouched.
    assert_eq!(std::fs::read(state.path().join("taken.npy")).unwrap(), b"x");
    assert!(!other.path().join("missing.npy").exists());
    assert!(!state.path().join("x.npy").exists());

    // A plain new name in the state directory works, by sdictl --by-path too.
    assert_eq!(block_on(call(&d.address, "Snapshot", &s("ok.npy"))), None);
    assert!(
        std::fs::metadata(state.path().join("ok.npy"))
            .unwrap()
            .len()
            > 80
    );
    stdout_of(&d.ctl(&["snapshot", "--by-path", &s("ok.png")]));
    assert!(image::open(state.path().join("ok.png")).is_ok());
    stdout_of(&d.ctl(&["record", "--by-path", &s("r.sdirec"), "--seconds", "0.3"]));
    assert!(
        std::fs::metadata(state.path().join("r.sdirec"))
            .unwrap()
            .len()
            > 0
    );
}

/// A newline in a client's path must not start a log line of its own.
#[test]
fn client_strings_do_not_split_log_lines() {
    require_dbus!();
    let state = tempfile::tempdir().unwrap();
    let log = tempfile::NamedTempFile::new().unwrap();
    let bus = Bus::start();
    let mut cmd = Daemon::command(&bus, &[], &["--state-dir", state.path().to_str().unwrap()]);
    cmd.env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdout(Stdio::null())
        .stderr(log.reopen().unwrap());
    let d = Daemon::spawn(&bus, &mut cmd);
    d.wait_ready();
    let injected = "INJECTED sdid: recording stopped";
    for dir in [state.path(), Path::new("/tmp")] {
        let path = format!("{}/a\n{injected}\r.sdirec", dir.display());
        let _ = block_on(call(&d.address, "StartRecording", &path));
        let _ = block_on(call(&d.address, "StopRecording", ""));
        let path = format!("{}/b\n{injected}.npy", dir.display());
        let _ = block_on(call(&d.address, "Snapshot", &path));
    }
    drop(d);
    let text = std::fs::read_to_string(log.path()).unwrap();
    for line in text.lines() {
        assert!(
            !line.contains("INJECTED") || line.contains("\\n"),
            "split log line: {line:?}\n{text}"
        );
        assert!(!line.trim_start().starts_with("INJECTED"), "{text}");
    }
    assert!(text.contains("INJECTED"), "the refusal is logged: {text}");
}
