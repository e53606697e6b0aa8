//! Where the y4m fallback goes: `sdid > log.txt` must not fill the log with
//! video (the FIFO in the runtime directory is used), while `sdid | reader`
//! streams y4m on the pipe.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use sdi_tests::dbus::{sdictl, Bus, Daemon};
use sdi_tests::require_dbus;

fn spawn_sdid(bus: &Bus, runtime_dir: &Path, stdout: Stdio) -> Daemon {
    spawn_sdid_at(bus, runtime_dir, stdout, "30")
}

fn spawn_sdid_at(bus: &Bus, runtime_dir: &Path, stdout: Stdio, frame_rate_hz: &str) -> Daemon {
    let mut cmd = Daemon::bare_command(bus, &[]);
    cmd.args(["--sink", "y4m"])
        .args(["--frame-rate-hz", frame_rate_hz, "--exposure-us", "2000"])
        .env("XDG_RUNTIME_DIR", runtime_dir)
        .stdout(stdout)
        .stderr(Stdio::null());
    let d = Daemon::spawn(bus, &mut cmd);
    d.wait_ready();
    d
}

#[test]
fn stdout_redirected_to_a_file_gets_no_video() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("log.txt");
    let file = std::fs::File::create(&log).unwrap();
    let _d = spawn_sdid(&bus, dir.path(), Stdio::from(file));
    let device = sdictl(&bus.address, &["get", "device"]);
    let fifo = dir.path().join("sdid-view.y4m");
    let device = String::from_utf8_lossy(&device.stdout).into_owned();
    assert!(
        device.trim().ends_with(&format!("-> {}", fifo.display())),
        "{device}"
    );
    // A reader on the FIFO gets the stream ...
    let mut head = [0u8; 9];
    std::fs::File::open(&fifo)
        .unwrap()
        .read_exact(&mut head)
        .unwrap();
    assert_eq!(&head, b"YUV4MPEG2");
    std::thread::sleep(Duration::from_millis(500));
    // ... and the log file none of it.
    let text = std::fs::read(&log).unwrap();
    assert!(
        !text.windows(9).any(|w| w == b"YUV4MPEG2") && text.len() < 4096,
        "{} bytes of stdout, starting {:?}",
        text.len(),
        String::from_utf8_lossy(&text[..text.len().min(64)])
    );
}

#[test]
fn stdout_pipe_gets_the_stream() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let mut d = spawn_sdid(&bus, dir.path(), Stdio::piped());
    let device = sdictl(&bus.address, &["get", "device"]);
    let device = String::from_utf8_lossy(&device.stdout).into_owned();
    assert!(device.trim().ends_with("-> stdout"), "{device}");
    let mut head = [0u8; 9];
    d.child
        .stdout
        .as_mut()
        .unwrap()
        .read_exact(&mut head)
        .unwrap();
    assert_eq!(&head, b"YUV4MPEG2");
    assert!(!dir.path().join("sdid-view.y4m").exists());
}

/// A reader that opens the FIFO right after the previous one closed (within
/// one frame period) gets the YUV4MPEG2 header first, like every reader:
/// `timeout 0.3 cat FIFO >/dev/null; head -c 9 FIFO`, 20 times, at 5 fps
/// (a frame period of 200 ms). No pause between the two: the second reader
/// opens a fresh FIFO, whatever the daemon has seen of the first one.
#[test]
fn every_new_fifo_reader_gets_the_header() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let _d = spawn_sdid_at(&bus, dir.path(), Stdio::null(), "5");
    let fifo = dir.path().join("sdid-view.y4m");
    let script = format!(
        "timeout 0.3 cat '{f}' >/dev/null; head -c 9 '{f}'",
        f = fifo.display()
    );
    let mut heads = Vec::new();
    for _ in 0..20 {
        let out = Command::new("sh").args(["-c", &script]).output().unwrap();
        heads.push(String::from_utf8_lossy(&out.stdout).into_owned());
    }
    let bad = heads.iter().filter(|h| *h != "YUV4MPEG2").count();
    assert_eq!(bad, 0, "{bad} of 20 readers got no header first: {heads:?}");
}
