//! Snapshots and recordings through file descriptors (`SnapshotToFd`,
//! `StartRecordingToFd`): sdictl creates the file as the caller and the
//! daemon writes through the descriptor, so places the sandboxed service
//! cannot see (home directories, /tmp under PrivateTmp) work.
//!
//! The daemon runs in its own mount namespace with an empty tmpfs over the
//! test's directory: the directory does not exist for it, so anything that
//! lands there went through the descriptor (and the path methods fail).

use std::fs;
use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use sdi_recording::{Record, RecordingReader};
use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::npy_file::read_npy;
use sdi_tests::process::stdout_of;
use sdi_tests::require_dbus;
use zbus::zvariant::Fd;

/// A directory hidden from the daemon: `outer/out`, with `outer` covered by
/// an empty tmpfs in the daemon's mount namespace.
struct Hidden {
    outer: PathBuf,
    out: PathBuf,
}

impl Hidden {
    fn new(name: &str) -> Self {
        let outer = std::env::temp_dir().join(format!("sdi-fd-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&outer);
        let out = outer.join("out");
        fs::create_dir_all(&out).unwrap();
        Self { outer, out }
    }

    /// `unshare` arguments that hide `outer` and exec sdid, or None when
    /// mount namespaces are not available to this user.
    fn wrapper(&self) -> Option<Vec<String>> {
        let base = ["unshare", "--mount", "--propagation", "private"];
        for extra in [&[][..], &["--map-root-user"][..]] {
            let probe = Command::new(base[0])
                .args(&base[1..])
                .args(extra)
                .args(["sh", "-c", "mount -t tmpfs sdi-hide \"$0\"", "/mnt"])
                .stderr(Stdio::null())
                .status();
            if probe.is_ok_and(|s| s.success()) {
                let mut w: Vec<String> = base.iter().map(|s| s.to_string()).collect();
                w.extend(extra.iter().map(|s| s.to_string()));
                w.extend([
                    "sh".into(),
                    "-c".into(),
                    "mount -t tmpfs -o size=1m sdi-hide \"$0\" && exec \"$@\"".into(),
                    self.outer.display().to_string(),
                ]);
                return Some(w);
            }
        }
        None
    }

    fn path(&self, name: &str) -> String {
        self.out.join(name).display().to_string()
    }

    fn entries(&self) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(&self.out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }
}

impl Drop for Hidden {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.outer);
    }
}

fn failed_with(out: &Output, code: i32, error: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "{stderr}");
    assert!(stderr.contains(error), "expected {error}: {stderr}");
}

fn start_hidden(bus: &Bus, hidden: &Hidden, extra: &[&str]) -> Daemon {
    match hidden.wrapper() {
        Some(w) => {
            let w: Vec<&str> = w.iter().map(String::as_str).collect();
            Daemon::start_wrapped(bus, &w, extra)
        }
        None => {
            eprintln!("NOTE: no mount namespace (unshare); the daemon can see the test directory");
            Daemon::start(bus, extra)
        }
    }
}

#[test]
fn snapshot_and_record_into_a_directory_the_daemon_cannot_see() {
    require_dbus!();
    let hidden = Hidden::new("hidden");
    let bus = Bus::start();
    let d = start_hidden(&bus, &hidden, &["--mode", "bipolar-colour"]);
    let hiding = hidden.wrapper().is_some();

    // By path the daemon cannot reach the directory...
    if hiding {
        let by_path = d.ctl(&["snapshot", "--by-path", &hidden.path("by-path.npy")]);
        failed_with(&by_path, 2, "org.sdi.Error.InvalidPath");
        let by_path = d.ctl(&["record", "--by-path", &hidden.path("by-path.sdirec")]);
        failed_with(&by_path, 2, "org.sdi.Error.InvalidPath");
    }
    // ... through a descriptor (the default) it writes there.
    let npy = hidden.path("snap.npy");
    let png = hidden.path("snap.png");
    assert_eq!(stdout_of(&d.ctl(&["snapshot", &npy])).trim(), npy);
    stdout_of(&d.ctl(&["snapshot", &png]));
    let (shape, _) = read_npy(Path::new(&npy));
    assert_eq!(shape, [240, 320]);
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (320, 240));
    // Created by the caller (this process), not handed over afterwards.
    let meta = fs::metadata(&npy).unwrap();
    assert_eq!(meta.uid(), nix::unistd::getuid().as_raw());

    // A relative path is resolved by sdictl in its own directory.
    let rel = Command::new(sdi_tests::dbus::bin("sdictl"))
        .current_dir(&hidden.out)
        .args(["--bus-address", &bus.address, "snapshot", "rel.npy"])
        .output()
        .unwrap();
    stdout_of(&rel);

    // Recording: the Recording property shows the caller's label; replay
    // reads every frame.
    let rec = hidden.path("run.sdirec");
    stdout_of(&d.ctl(&["record", &rec]));
    assert_eq!(stdout_of(&d.ctl(&["get", "recording"])).trim(), rec);
    std::thread::sleep(std::time::Duration::from_millis(700));
    let stop = stdout_of(&d.ctl(&["--json", "stop"]));
    let summary: serde_json::Value = serde_json::from_str(stop.trim()).unwrap();
    assert_eq!(summary["path"], rec.as_str());
    let frames = summary["frames"].as_u64().unwrap();
    assert!(frames > 0, "{summary}");
    let mut reader = RecordingReader::open(Path::new(&rec)).unwrap();
    assert_eq!(reader.header().mode, "bipolar-colour");
    let mut n = 0;
    let mut ended = false;
    while let Some(r) = reader.next_record() {
        match r {
            Record::Frame { .. } => n += 1,
            Record::End { frames: f, .. } => {
                assert_eq!(f, frames);
                ended = true;
            }
            Record::Dark { .. } => {}
        }
    }
    assert!(ended && n == frames, "{n} frames of {frames}, end {ended}");

    // Only the finished files, no temporary ones.
    assert_eq!(
        hidden.entries(),
        ["rel.npy", "run.sdirec", "snap.npy", "snap.png"]
    );
}

#[test]
fn sdictl_leaves_nothing_behind_on_errors() {
    require_dbus!();
    let hidden = Hidden::new("errors");
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let first = hidden.path("first.sdirec");
    stdout_of(&d.ctl(&["record", &first]));
    // Busy: the second recording's file must not appear.
    let second = d.ctl(&["record", &hidden.path("second.sdirec")]);
    failed_with(&second, 4, "org.sdi.Error.Busy");
    stdout_of(&d.ctl(&["stop"]));
    // Existing file: untouched.
    fs::write(hidden.out.join("mine.npy"), b"keep").unwrap();
    failed_with(&d.ctl(&["snapshot", &hidden.path("mine.npy")]), 2, "exists");
    assert_eq!(fs::read(hidden.out.join("mine.npy")).unwrap(), b"keep");
    // Wrong extension, missing directory: refused before anything exists.
    failed_with(
        &d.ctl(&["snapshot", &hidden.path("x.jpg")]),
        2,
        ".png, .npy",
    );
    failed_with(&d.ctl(&["record", &hidden.path("x.npy")]), 2, ".sdirec");
    failed_with(
        &d.ctl(&["snapshot", &hidden.path("missing/x.npy")]),
        2,
        "cannot create",
    );
    assert_eq!(hidden.entries(), ["first.sdirec", "mine.npy"]);
}

/// Calls a method with a descriptor and returns the D-Bus error name, if any.
async fn call_with_fd(
    conn: &zbus::Connection,
    method: &str,
    fd: Fd<'_>,
    arg: &str,
) -> Option<String> {
    match conn
        .call_method(
            Some("org.sdi.Daemon"),
            "/org/sdi/Camera0",
            Some("org.sdi.Camera1"),
            method,
            &(fd, arg),
        )
        .await
    {
        Ok(_) => None,
        Err(zbus::Error::MethodError(name, _, _)) => Some(name.to_string()),
        Err(e) => panic!("{method}: {e}"),
    }
}

#[test]
fn bad_descriptors_get_typed_errors() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let rt = sdi_tests::dbus::runtime();
    rt.block_on(async {
        let conn = zbus::connection::Builder::address(bus.address.as_str())
            .unwrap()
            .build()
            .await
            .unwrap();
        let invalid_fd = Some("org.sdi.Error.InvalidFd".to_owned());

        let (sock, _peer) = UnixStream::pair().unwrap();
        let (pipe_r, pipe_w) = nix::unistd::pipe().unwrap();
        let null = fs::OpenOptions::new()
            .write(true)
            .open("/dev/null")
            .unwrap();
        let full_path = dir.path().join("full.npy");
        fs::File::create(&full_path)
            .unwrap()
            .write_all(b"data")
            .unwrap();
        let full = fs::OpenOptions::new().write(true).open(&full_path).unwrap();
        let empty_path = dir.path().join("empty.npy");
        fs::File::create(&empty_path).unwrap();
        let read_only = fs::File::open(&empty_path).unwrap();
        let directory = fs::File::open(dir.path()).unwrap();
        let procfs = fs::OpenOptions::new()
            .write(true)
            .open("/proc/self/comm")
            .unwrap();

        for method in ["SnapshotToFd", "StartRecordingToFd"] {
            let arg = if method == "SnapshotToFd" { "npy" } else { "" };
            for (what, fd) in [
                ("socket", Fd::from(&sock)),
                ("pipe", Fd::from(&pipe_w)),
                ("/dev/null", Fd::from(&null)),
                ("non-empty file", Fd::from(&full)),
                ("read-only file", Fd::from(&read_only)),
                ("directory", Fd::from(&directory)),
                ("procfs file", Fd::from(&procfs)),
            ] {
                assert_eq!(
                    call_with_fd(&conn, method, fd, arg).await,
                    invalid_fd,
                    "{method} with a {what}"
                );
            }
        }
        drop(pipe_r);
        let good = fs::File::create(dir.path().join("good.npy")).unwrap();
        assert_eq!(
            call_with_fd(&conn, "SnapshotToFd", Fd::from(&good), "jpeg").await,
            Some("org.sdi.Error.OutOfRange".to_owned())
        );
        assert_eq!(
            call_with_fd(&conn, "StartRecordingToFd", Fd::from(&good), "a\u{1b}[2J").await,
            Some("org.sdi.Error.InvalidPath".to_owned())
        );
        // Nothing was written, nothing is recording, and a good call works.
        assert_eq!(fs::read(&full_path).unwrap(), b"data");
        assert_eq!(fs::metadata(&empty_path).unwrap().len(), 0);
        assert_eq!(
            call_with_fd(&conn, "SnapshotToFd", Fd::from(&good), "npy").await,
            None
        );
    });
    let (_, data) = read_npy(&dir.path().join("good.npy"));
    assert!(!data.is_empty());
    assert_eq!(stdout_of(&d.ctl(&["get", "recording"])).trim(), "");
}

/// Under systemd (INVOCATION_ID set) the daemon's /tmp is private: a path
/// there is refused with a hint, while the descriptor way works.
#[test]
fn service_refuses_paths_into_its_private_tmp() {
    require_dbus!();
    let dir = tempfile::tempdir_in("/tmp").unwrap();
    let bus = Bus::start();
    let d = Daemon::start_wrapped(&bus, &["env", "INVOCATION_ID=sdi-test"], &[]);
    let by_path = dir.path().join("by-path.npy");
    let out = d.ctl(&["snapshot", "--by-path", by_path.to_str().unwrap()]);
    failed_with(&out, 2, "org.sdi.Error.InvalidPath");
    assert!(String::from_utf8_lossy(&out.stderr).contains("PrivateTmp"));
    assert!(!by_path.exists());
    let by_fd = dir.path().join("by-fd.npy");
    stdout_of(&d.ctl(&["snapshot", by_fd.to_str().unwrap()]));
    assert!(by_fd.is_file());
}
