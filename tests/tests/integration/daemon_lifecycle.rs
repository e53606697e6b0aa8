//! How sdid starts and ends: SIGHUP finishes a recording like SIGTERM; a
//! private session bus dies with `sdid --session` even on kill -9; shutdown
//! stays bounded when the source hangs; a second instance exits before it
//! touches a sink; a warning that does not change is logged once; a
//! setting of `sdid.toml` the board cannot take stops the start with the
//! board's range.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use nix::sys::signal::Signal;
use sdi_recording::{Record, RecordingReader};
use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::process::{signal, Reaped};
use sdi_tests::require_dbus;
use sdi_tests::sdid_command::SdidCommand;
use sdi_tests::wait::wait_for;
use strum::IntoEnumIterator;

/// Frames and whether the end record is there.
fn frames_and_end(path: &Path) -> (usize, bool) {
    let mut frames = 0;
    let mut ended = false;
    for rec in RecordingReader::open(path).unwrap() {
        match rec {
            Record::Frame { .. } => frames += 1,
            Record::End { .. } => ended = true,
            Record::Dark { .. } => {}
        }
    }
    (frames, ended)
}

/// `cmd` with stderr to `log` (RUST_LOG=info) and stdout to /dev/null.
fn logged<'a>(cmd: &'a mut Command, log: &Path) -> &'a mut Command {
    let log = std::fs::File::create(log).unwrap();
    cmd.env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(log)
}

/// Starts sdid on `bus` with stderr to `log` (RUST_LOG=info).
fn spawn_logged(bus: &Bus, extra: &[&str], log: &Path) -> Daemon {
    Daemon::spawn(bus, logged(&mut Daemon::command(bus, &[], extra), log))
}

/// Starts sdid on `bus` streaming y4m into the default FIFO of
/// `runtime_dir`, with stderr to `log` (RUST_LOG=info).
fn spawn_on_fifo(bus: &Bus, runtime_dir: &Path, log: &Path) -> Daemon {
    let mut cmd = Daemon::bare_command(bus, &[]);
    cmd.args(["--sink", "y4m"])
        .args(["--frame-rate-hz", "30", "--exposure-us", "2000"])
        .env("XDG_RUNTIME_DIR", runtime_dir);
    Daemon::spawn(bus, logged(&mut cmd, log))
}

#[test]
fn sighup_finishes_the_recording_and_says_so() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("sdid.log");
    let mut d = spawn_logged(&bus, &[], &log);
    d.wait_ready();
    let rec = dir.path().join("h.sdirec");
    let out = d.ctl(&["record", rec.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::thread::sleep(Duration::from_millis(700));
    let status = d.signal(Signal::SIGHUP);
    assert!(status.success(), "sdid exit {status:?}");
    let (frames, ended) = frames_and_end(&rec);
    assert!(ended, "no end record after SIGHUP");
    assert!(frames >= 5, "{frames} frames");
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.contains("SIGHUP: shutting down"), "{text}");
    assert!(text.contains("recording finalized"), "{text}");
}

/// Pids of the children of `pid` (all its threads).
fn children(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    for task in std::fs::read_dir(format!("/proc/{pid}/task"))
        .into_iter()
        .flatten()
    {
        let Ok(task) = task else { continue };
        if let Ok(s) = std::fs::read_to_string(task.path().join("children")) {
            out.extend(s.split_whitespace().filter_map(|p| p.parse::<u32>().ok()));
        }
    }
    out
}

/// Whether `pid` still runs (a zombie waiting for a reaper does not).
fn running(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => stat
            .rsplit_once(')')
            .is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z')),
        Err(_) => false,
    }
}

/// `sdid --session` with no session bus around: it starts a private one and
/// announces its address on stderr. Returns sdid (killed when dropped, so a
/// failing test leaves no daemon and bus behind), its stderr (read up to the
/// announcement), the address and the lines read so far, once sdid answers
/// on that bus.
fn start_with_private_bus(
    runtime: &Path,
) -> (
    Reaped,
    BufReader<std::process::ChildStderr>,
    String,
    Vec<String>,
) {
    let mut child = SdidCommand::new()
        .args(["--session"])
        .y4m("-")
        .log("info")
        .command()
        .env_remove("DBUS_SESSION_BUS_ADDRESS")
        .env("XDG_RUNTIME_DIR", runtime)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start sdid --session");
    let err = child.stderr.take().expect("sdid's stderr is piped");
    let child = Reaped(child);
    let mut err = BufReader::new(err);
    let (mut address, mut lines) = (None, Vec::new());
    let mut line = String::new();
    while address.is_none() && err.read_line(&mut line).unwrap_or(0) > 0 {
        if let Some(rest) = line
            .trim()
            .strip_prefix("export DBUS_SESSION_BUS_ADDRESS='")
        {
            address = Some(rest.trim_end_matches('\'').to_owned());
        }
        lines.push(std::mem::take(&mut line));
    }
    let address = address.unwrap_or_else(|| panic!("sdid announced no private bus: {lines:#?}"));
    let t0 = Instant::now();
    loop {
        let out = sdi_tests::dbus::sdictl(&address, &["get", "mode"]);
        if out.status.success() {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "sdid did not come up on {address}: sdictl {}: {}; sdid running: {}, its children: {:?}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim(),
            running(child.0.id()),
            children(child.0.id())
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    (child, err, address, lines)
}

/// The private bus's own messages (as root without CAP_SYS_RESOURCE,
/// dbus-daemon warns that it cannot raise its fd limit, at the moment sdid
/// announces the address) go through sdid's log a line at a time, so they
/// never land inside the announcement: written straight to the shared
/// stderr they did, 4 runs in 10 under load, and the address read was the
/// warning.
#[test]
fn the_private_bus_announcement_stays_whole() {
    require_dbus!();
    let runtime = tempfile::tempdir().unwrap();
    let (mut child, mut err, address, mut lines) = start_with_private_bus(runtime.path());
    assert!(address.starts_with("unix:"), "address {address:?}");
    signal(child.0.id(), Signal::SIGTERM);
    let mut rest = String::new();
    let _ = err.read_to_string(&mut rest);
    let _ = child.0.wait();
    lines.extend(rest.lines().map(str::to_owned));
    let raw: Vec<&String> = lines
        .iter()
        .filter(|l| l.trim_start().starts_with("dbus-daemon["))
        .collect();
    assert!(
        raw.is_empty(),
        "dbus-daemon wrote to sdid's stderr directly: {raw:#?}"
    );
}

#[test]
fn kill_9_takes_the_private_session_bus_along() {
    require_dbus!();
    let runtime = tempfile::tempdir().unwrap();
    let (mut child, _err, address, _) = start_with_private_bus(runtime.path());
    let bus_pids = children(child.0.id());
    assert!(!bus_pids.is_empty(), "no dbus-daemon child");
    signal(child.0.id(), Signal::SIGKILL);
    let _ = child.0.wait();
    let t0 = Instant::now();
    while bus_pids.iter().any(|&p| running(p)) {
        if t0.elapsed() > Duration::from_secs(5) {
            for &p in &bus_pids {
                // Cleaning up the leaked bus this test started.
                signal(p, Signal::SIGKILL);
            }
            panic!("the private dbus-daemon {bus_pids:?} outlived sdid by 5 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        !sdi_tests::dbus::sdictl(&address, &["get", "mode"])
            .status
            .success(),
        "the private bus at {address} still answers"
    );
}

/// A replay from a FIFO whose writer stops mid-recording: the source hangs
/// in a read (as on frozen storage). SIGTERM still ends sdid well within the
/// unit's TimeoutStopSec (15 s), and the log says what was abandoned.
#[test]
fn sigterm_is_bounded_when_the_source_hangs() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("src.sdirec");
    sdi_tests::dbus::record_sim(&rec, 0.5);
    let bytes = std::fs::read(&rec).unwrap();
    let fifo = dir.path().join("stuck.sdirec");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
    // Writes the first half of the recording, then holds the FIFO open.
    let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
    let fifo2 = fifo.clone();
    let feeder = std::thread::spawn(move || {
        let mut w = std::fs::OpenOptions::new()
            .write(true)
            .open(&fifo2)
            .unwrap();
        let _ = w.write_all(&bytes[..bytes.len() / 2]);
        let _ = done_rx.recv();
    });
    let bus = Bus::start();
    let log = dir.path().join("sdid.log");
    let mut d = spawn_logged(
        &bus,
        &["--replay", fifo.to_str().unwrap(), "--mode", "raw"],
        &log,
    );
    d.wait_ready();
    // Let it play what there is and hang in the read that follows.
    std::thread::sleep(Duration::from_secs(2));
    let t0 = Instant::now();
    let status = d.signal(Signal::SIGTERM);
    let took = t0.elapsed();
    let _ = done_tx.send(());
    let _ = feeder.join();
    let text = std::fs::read_to_string(&log).unwrap();
    eprintln!("SIGTERM to exit with a hung source: {took:?} ({status:?})");
    assert!(
        took < Duration::from_secs(12),
        "shutdown took {took:?}\n{text}"
    );
    assert!(text.contains("did not stop within"), "{text}");
}

/// A second sdid on the same bus exits at once, before it opens a sink:
/// the first one's FIFO reader sees one well-formed stream.
#[test]
fn a_second_instance_leaves_the_first_ones_fifo_alone() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("sdid-view.y4m");
    let first = spawn_on_fifo(&bus, dir.path(), &dir.path().join("first.log"));
    first.wait_ready();
    let reader = std::fs::File::open(&fifo).unwrap();
    let (w, h) = (320usize, 240usize);
    // Reads 2 s of stream in the background.
    let collector = std::thread::spawn(move || {
        let mut r = reader;
        let mut buf = Vec::new();
        let mut chunk = vec![0u8; 1 << 16];
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(2) {
            match r.read(&mut chunk) {
                Ok(0) | Err(_) => break,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
            }
        }
        buf
    });
    std::thread::sleep(Duration::from_millis(300));
    let log = dir.path().join("second.log");
    let mut second = spawn_on_fifo(&bus, dir.path(), &log);
    let status = wait_for("the second sdid to exit", Duration::from_secs(20), || {
        second.child.try_wait().unwrap()
    });
    assert!(!status.success());
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.contains("already owned"), "{text}");
    assert!(
        !text.contains("y4m"),
        "the second sdid opened its sink:\n{text}"
    );
    let stream = collector.join().unwrap();
    drop(first);
    // One header, then whole frames only.
    let header_end = stream.iter().position(|&b| b == b'\n').unwrap() + 1;
    assert!(stream.starts_with(b"YUV4MPEG2"));
    let frame = 6 + 3 * w * h;
    let body = &stream[header_end..];
    let whole = body.len() / frame;
    assert!(whole >= 10, "{whole} frames");
    for i in 0..whole {
        assert_eq!(
            &body[i * frame..i * frame + 6],
            b"FRAME\n",
            "frame {i} misaligned"
        );
    }
}

#[test]
fn an_unchanged_light_travel_warning_is_logged_once() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("sdid.log");
    // depth-edge's scene is deep enough for the warning at 12 MHz.
    let d = spawn_logged(
        &bus,
        &["--mode", "depth-edge", "--modulation-hz", "12e6"],
        &log,
    );
    d.wait_ready();
    for us in ["1000", "1500", "2000"] {
        let out = d.ctl(&["set", "exposure-us", us]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // Nor when a mode with another scene comes and goes.
    for mode in ["raw", "depth-edge", "raw", "depth-edge"] {
        let out = d.ctl(&["set-mode", mode]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    drop(d);
    let text = std::fs::read_to_string(&log).unwrap();
    let n = text.matches("light travel").count();
    assert_eq!(n, 1, "{n} light-travel warnings:\n{text}");
}

/// The README's main job as a newcomer runs it (`--backend sim`, sink
/// auto, no module, no PipeWire): a first screen that says which sink runs,
/// why and what to open, and no warning in any mode with the defaults.
#[test]
fn the_defaults_give_a_clean_first_screen_in_every_mode() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("sdid.log");
    let mut cmd = Daemon::bare_command(&bus, &[]);
    cmd.args(["--backend", "sim"])
        .env("XDG_RUNTIME_DIR", dir.path())
        .env_remove("PIPEWIRE_REMOTE")
        .env_remove("INVOCATION_ID")
        .env_remove("JOURNAL_STREAM");
    let d = Daemon::spawn(&bus, logged(&mut cmd, &log));
    d.wait_ready();
    for mode in sdi_core::mode::ModeId::iter() {
        let out = d.ctl(&["set-mode", mode.name()]);
        assert!(out.status.success(), "{mode:?}: {out:?}");
        // A few frames in the mode (the warnings come with the first).
        std::thread::sleep(Duration::from_millis(300));
    }
    drop(d);
    let text = std::fs::read_to_string(&log).unwrap();
    for bad in [" WARN ", " ERROR "] {
        assert!(!text.contains(bad), "{bad:?} with the defaults:\n{text}");
    }
    let fifo = dir.path().join("sdid-view.y4m");
    for line in [
        "sdid: simulator (TI OPT8241), mode raw, published as a y4m stream".to_string(),
        "  why:     no v4l2loopback ".to_string(),
        format!("  view:    ffplay {}", fifo.display()),
        "  control: sdictl set-mode".to_string(),
    ] {
        assert!(text.contains(&line), "no {line:?} in:\n{text}");
    }
    // A few lines: nothing else at info level before the first screen ends.
    let screen = text
        .lines()
        .take_while(|l| !l.starts_with("  control:"))
        .count();
    assert!(screen <= 6, "a first screen of {screen} lines:\n{text}");
}

/// `sdid.toml` values are checked against the board's limits before any
/// board is looked for: a frame rate the board's output port cannot carry
/// at full resolution ends the start with the range and what sets it, not
/// with "no board" (the host has none).
#[test]
fn a_board_setting_out_of_the_boards_range_stops_the_start_with_the_range() {
    require_dbus!();
    let dir = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    for (line, name, range) in [
        ("frame_rate_hz = 60.0", "frame_rate_hz", "31.25"),
        ("modulation_hz = 5e6", "modulation_hz", "9375000"),
    ] {
        let config = dir.path().join("sdid.toml");
        std::fs::write(&config, format!("backend = \"opt8241\"\n{line}\n")).unwrap();
        let out = Daemon::bare_command(&bus, &[])
            .args(["--sink", "y4m", "--y4m-path", "-", "--config"])
            .arg(&config)
            .stdout(Stdio::null())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{line}: {err}");
        assert_ne!(out.status.code(), Some(101), "panicked: {err}");
        assert!(
            err.contains(name) && err.contains("out of range for the board") && err.contains(range),
            "{line}: {err}"
        );
    }
}
