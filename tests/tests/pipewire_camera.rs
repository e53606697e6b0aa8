//! The PipeWire sink on the host, without v4l2loopback: a private bus,
//! `pipewire` and `wireplumber` under a temporary XDG_RUNTIME_DIR, then
//! `sdid --backend sim --sink pipewire`. `pw-dump` must list the camera node
//! (Video/Source, media.role Camera), `gst-launch-1.0 pipewiresrc` must read
//! frames whose CRC-32 sdid logged as published (the exact bytes), through a
//! mode switch, a second format and the data node; a reader keeps its
//! stream while sdid restarts (the nodes belong to the camera process sdid
//! starts), seeing the "no signal" card and then the new sdid's frames.
//! With several cameras each has its own camera process and nodes, named
//! by its serial, in a session and behind the system service's feeds.

use std::collections::{HashMap, HashSet};
use std::process::Stdio;
use std::time::{Duration, Instant};

use sdi_tests::dbus::sdictl;
use sdi_tests::pipewire::{
    frame_crcs, FrameLog, Session, SUSPEND_TIMEOUT_KEY, WIREPLUMBER_SUSPEND,
};
use sdi_tests::process::Reaped;
use sdi_tests::require_pipewire;
use sdi_tests::sdid_command::SdidCommand;
use sdi_tests::wait::wait_for;

const VIEW: &str = "sdi-camera";
const DATA: &str = "sdi-camera-data";
const TIMEOUT: Duration = Duration::from_secs(30);
/// The view size (v4l2loopback's view profile) and the simulator's sensor.
const VIEW_W: usize = 640;
const VIEW_H: usize = 480;
const SENSOR_W: usize = 320;
const SENSOR_H: usize = 240;
const FRAMES: u32 = 40;

struct Sdid {
    _child: Reaped,
    log: FrameLog,
    address: String,
}

impl Sdid {
    /// Starts sdid; its stderr (and the camera process's, which inherits
    /// it) goes to the session's `sdid.log`.
    fn start(s: &Session, extra: &[&str]) -> Self {
        let log = FrameLog::file(s.dir.path().join("sdid.log"));
        let child = SdidCommand::client_of(s)
            .bus(&s.bus.address)
            .sim()
            .args(["--frame-rate-hz", "30", "--exposure-us", "2000"])
            .args(extra)
            .log("info,sdid::pipewire::frames=trace")
            .command()
            .stdout(Stdio::null())
            .stderr(log.writer())
            .spawn()
            .expect("start sdid");
        let child = Reaped(child);
        let address = s.bus.address.clone();
        let t0 = Instant::now();
        while !sdictl(&address, &["get", "mode"]).status.success() {
            assert!(
                t0.elapsed() < TIMEOUT,
                "sdid did not come up:\n{}",
                log.text()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        Self {
            _child: child,
            log,
            address,
        }
    }

    /// Waits until sdid answers for each of `serials` (`--camera SERIAL`).
    fn wait_for_cameras(&self, serials: &[&str]) {
        wait_for("every camera on the bus", TIMEOUT, || {
            serials
                .iter()
                .all(|c| {
                    sdictl(&self.address, &["--camera", c, "get", "mode"])
                        .status
                        .success()
                })
                .then_some(())
        });
    }

    fn ctl(&self, args: &[&str]) -> String {
        let out = sdictl(&self.address, args);
        assert!(
            out.status.success(),
            "sdictl {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }
}

fn prop<'a>(p: &'a HashMap<String, serde_json::Value>, key: &str) -> &'a str {
    p.get(key).and_then(|v| v.as_str()).unwrap_or("")
}

/// The CRC-32 of each frame in `data`, read whole.
fn crcs_of(data: &[u8], frame_bytes: usize) -> Vec<String> {
    assert_eq!(data.len() % frame_bytes, 0, "a partial frame was read");
    frame_crcs(data, frame_bytes)
}

/// Asserts that every frame of `crcs` is one sdid published on `stream` in
/// `format` while in `mode` (same CRC-32), that they are live (not one
/// still) and that their PTS rise steadily; returns the CRCs.
fn check_published(
    d: &Sdid,
    crcs: Vec<String>,
    stream: &str,
    format: &str,
    mode: &str,
) -> Vec<String> {
    assert!(crcs.len() >= 30, "only {} frames read", crcs.len());
    let matches = |p: &HashMap<String, String>, crc: &str| {
        p.get("crc32").map(String::as_str) == Some(crc)
            && p.get("stream").map(String::as_str) == Some(stream)
            && p.get("format").map(String::as_str) == Some(format)
            && p.get("mode").map(String::as_str) == Some(mode)
    };
    // The log line is written before the buffer is queued; the collector
    // thread may still be behind: poll.
    let t0 = Instant::now();
    let missing = loop {
        let published = d.log.published();
        let missing: Vec<&String> = crcs
            .iter()
            .filter(|c| !published.iter().any(|p| matches(p, c)))
            .collect();
        if missing.is_empty() || t0.elapsed() > Duration::from_secs(10) {
            break missing.into_iter().cloned().collect::<Vec<_>>();
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(
        missing.is_empty(),
        "{} of {} frames read from {stream} were not published by sdid as {format} in mode {mode}: {missing:?}",
        missing.len(),
        crcs.len()
    );
    let distinct: HashSet<&String> = crcs.iter().collect();
    assert!(
        distinct.len() > crcs.len() / 2,
        "{stream}: only {} distinct frames of {}",
        distinct.len(),
        crcs.len()
    );
    // This stream's published buffers, in publishing order: (seq, PTS,
    // capture stamp in us, CLOCK_MONOTONIC when published), all in ns but the
    // capture stamp.
    let mut stamps: Vec<(u64, i64, i64, i64)> = d
        .log
        .published()
        .iter()
        .filter(|p| p.get("stream").map(String::as_str) == Some(stream))
        .filter_map(|p| {
            let n = |k: &str| p.get(k)?.parse::<i64>().ok();
            let seq = p.get("seq")?.parse().ok()?;
            Some((seq, n("pts_ns")?, n("capture_us")?, n("published_ns")?))
        })
        .collect();
    stamps.sort_unstable();
    // PTS strictly increasing in publishing order, at about the frame rate.
    assert!(
        stamps.windows(2).all(|w| w[1].1 > w[0].1),
        "{stream}: PTS not increasing"
    );
    // PTS is the frame's capture time (as on the loopback node): never later
    // than the moment it was published, and the capture stamp itself unless
    // it had to be moved 1 ns past the previous frame's.
    let late: Vec<_> = stamps.iter().filter(|(_, pts, _, at)| pts > at).collect();
    assert!(late.is_empty(), "{stream}: PTS after publishing: {late:?}");
    let captured = stamps
        .iter()
        .filter(|&&(_, pts, capture_us, _)| pts == capture_us * 1000)
        .count();
    assert!(
        captured * 10 >= stamps.len() * 9,
        "{stream}: only {captured} of {} PTS are the capture time",
        stamps.len()
    );
    let mut gaps_ms: Vec<f64> = stamps
        .windows(2)
        .map(|w| (w[1].1 - w[0].1) as f64 * 1e-6)
        .collect();
    gaps_ms.sort_by(f64::total_cmp);
    let median = gaps_ms[gaps_ms.len() / 2];
    assert!(
        (15.0..=100.0).contains(&median),
        "{stream}: median frame interval {median:.1} ms at 30 fps"
    );
    eprintln!(
        "ok: {} {format} frames of {stream} in mode {mode} match sdid's published CRC-32s ({} distinct, median interval {median:.1} ms)",
        crcs.len(),
        distinct.len()
    );
    crcs
}

/// The view is the 320x240 sensor image scaled 2x: every 2x2 block is one colour.
fn assert_doubled_rgb(frame: &[u8]) {
    let px = |x: usize, y: usize| &frame[(y * VIEW_W + x) * 3..(y * VIEW_W + x) * 3 + 3];
    for y in (0..VIEW_H).step_by(2) {
        for x in (0..VIEW_W).step_by(2) {
            let p = px(x, y);
            assert!(
                px(x + 1, y) == p && px(x, y + 1) == p && px(x + 1, y + 1) == p,
                "the view is not the sensor image doubled at ({x}, {y})"
            );
        }
    }
}

fn wait_node(s: &Session, name: &str) -> HashMap<String, serde_json::Value> {
    wait_for(&format!("node {name} in pw-dump"), TIMEOUT, || s.node(name))
}

#[test]
fn pipewire_camera_node_frames_mode_switch_and_restart() {
    require_pipewire!();
    let s = Session::start();
    let d = Sdid::start(&s, &["--sink", "pipewire"]);

    let view = wait_node(&s, VIEW);
    assert_eq!(prop(&view, "media.class"), "Video/Source", "{view:?}");
    assert_eq!(prop(&view, "media.role"), "Camera", "{view:?}");
    assert_eq!(prop(&view, "node.description"), "SDI camera (raw)");
    let data = wait_node(&s, DATA);
    assert_eq!(prop(&data, "media.class"), "Video/Source", "{data:?}");
    assert_ne!(prop(&data, "media.role"), "Camera", "{data:?}");
    eprintln!(
        "ok: pw-dump: {VIEW}: media.class {}, media.role {}, description {:?}",
        prop(&view, "media.class"),
        prop(&view, "media.role"),
        prop(&view, "node.description")
    );
    let device = d.ctl(&["get", "device"]);
    assert!(device.contains("PipeWire node \"sdi-camera\""), "{device}");

    // RGB from the camera node.
    let rgb_bytes = VIEW_W * VIEW_H * 3;
    let rgb = s.read_frames(VIEW, "video/x-raw,format=RGB", FRAMES, TIMEOUT);
    let raw_crcs = check_published(&d, crcs_of(&rgb, rgb_bytes), VIEW, "RGB", "raw");
    rgb.chunks_exact(rgb_bytes).for_each(assert_doubled_rgb);

    // Never suspended: WirePlumber suspends a node idle for 5 s, and a
    // suspend while the next reader's link allocates its buffers fails
    // that link (PipeWire 1.4: Chromium's "Buffer allocation failed" when
    // it reopens the camera seconds after its probe). The camera asks for
    // no suspend; the node idles past WirePlumber's 5 s and is still idle.
    assert_eq!(
        view.get(SUSPEND_TIMEOUT_KEY),
        Some(&serde_json::json!(0)),
        "{view:?}"
    );
    let t_idle = Instant::now();
    std::thread::sleep(WIREPLUMBER_SUSPEND + Duration::from_secs(2));
    let state = s.node_state(VIEW);
    assert_eq!(
        state.as_deref(),
        Some("idle"),
        "{VIEW} {:.1} s after its reader left",
        t_idle.elapsed().as_secs_f64()
    );
    eprintln!(
        "ok: {VIEW} still idle (not suspended) {:.1} s after its reader left",
        t_idle.elapsed().as_secs_f64()
    );

    // The raw data node: Y16 at the sensor size.
    let y16 = s.read_frames(DATA, "video/x-raw,format=GRAY16_LE", 30, TIMEOUT);
    let y16 = crcs_of(&y16, SENSOR_W * SENSOR_H * 2);
    check_published(&d, y16, DATA, "Y16", "raw");

    // A mode switch: the description follows, and the frames are the new mode's.
    d.ctl(&["set-mode", "depth-edge"]);
    wait_for("the node description to follow the mode", TIMEOUT, || {
        s.node(VIEW)
            .filter(|p| prop(p, "node.description") == "SDI camera (depth-edge)")
    });
    let yuyv = s.read_frames(VIEW, "video/x-raw,format=YUY2", 30, TIMEOUT);
    let yuyv = crcs_of(&yuyv, VIEW_W * VIEW_H * 2);
    let edge_crcs = check_published(&d, yuyv, VIEW, "YUYV", "depth-edge");
    assert!(edge_crcs.iter().all(|c| !raw_crcs.contains(c)));

    // A restart: the node stays, and a reader that started before it keeps
    // its stream: the no-signal card while no sdid runs, then the new
    // sdid's frames (WirePlumber would end the stream if the node went away).
    let mut reader = s.stream_frames(VIEW, "video/x-raw,format=RGB", rgb_bytes);
    wait_for("frames in the running reader", TIMEOUT, || {
        (reader.crcs().len() >= 5).then_some(())
    });
    let pid = d._child.0.id();
    drop(d);
    let card = frame_crcs(&no_signal_rgb(), rgb_bytes);
    wait_for("the no-signal card in the running reader", TIMEOUT, || {
        reader.crcs().contains(&card[0]).then_some(())
    });
    assert!(
        s.node(VIEW).is_some(),
        "the node went away with sdid (pid {pid})"
    );
    let d = Sdid::start(&s, &["--sink", "pipewire", "--mode", "bipolar-colour"]);
    wait_for(
        "the node description to follow the new sdid",
        TIMEOUT,
        || {
            s.node(VIEW)
                .filter(|p| prop(p, "node.description") == "SDI camera (bipolar-colour)")
        },
    );
    let is_new = |c: &String| {
        d.log.published().iter().any(|p| {
            p.get("crc32") == Some(c) && p.get("mode").map(String::as_str) == Some("bipolar-colour")
        })
    };
    let from_new = wait_for(
        "30 frames of the new sdid in the running reader",
        TIMEOUT,
        || {
            let crcs = reader.crcs();
            let first = crcs.iter().position(is_new)?;
            (crcs.len() >= first + 30).then(|| crcs[first..first + 30].to_vec())
        },
    );
    assert!(reader.running(), "the reader did not survive the restart");
    check_published(&d, from_new, VIEW, "RGB", "bipolar-colour");
    eprintln!("ok: one gst-launch reader kept its stream across an sdid restart (no-signal card, then the new sdid's frames)");
}

/// The no-signal card as RGB at the view size.
fn no_signal_rgb() -> Vec<u8> {
    sdi_core::view::no_signal_grey(VIEW_W, VIEW_H)
        .iter()
        .flat_map(|&g| [g, g, g])
        .collect()
}

/// The camera process outlives sdid by its linger time while no reader
/// streams, then ends and takes the nodes along.
#[test]
fn camera_process_ends_after_sdid_and_readers_are_gone() {
    require_pipewire!();
    let s = Session::start();
    let d = Sdid::start(&s, &["--sink", "pipewire"]);
    wait_node(&s, VIEW);
    let gone_at = Instant::now();
    drop(d);
    let linger = sdi_daemon::sink::pipewire::LINGER;
    while gone_at.elapsed() < linger - Duration::from_secs(5) {
        assert!(
            s.node(VIEW).is_some(),
            "the node went away {:?} after sdid, before the linger time",
            gone_at.elapsed()
        );
        std::thread::sleep(Duration::from_secs(1));
    }
    wait_for("the camera process to end", linger + TIMEOUT, || {
        s.node(VIEW).is_none().then_some(())
    });
    let log = FrameLog::file(s.dir.path().join("sdid.log")).text();
    assert!(
        log.contains("no reader: exiting"),
        "the camera process did not say why it ended:\n{log}"
    );
    eprintln!(
        "ok: the camera ended {:.1} s after sdid (linger {} s)",
        gone_at.elapsed().as_secs_f64(),
        linger.as_secs()
    );
}

#[test]
fn sink_auto_prefers_pipewire_then_y4m() {
    require_pipewire!();
    let s = Session::start();
    // A label no loopback device has, so auto passes over v4l2loopback even
    // where the module is loaded.
    let config = s.dir.path().join("sdid.toml");
    std::fs::write(&config, "[output]\nlabel = \"sdi-test absent loopback\"\n")
        .expect("write config");
    let config = config.to_string_lossy().into_owned();
    {
        let d = Sdid::start(&s, &["--sink", "auto", "--config", &config]);
        let device = d.ctl(&["get", "device"]);
        assert!(
            device.contains("PipeWire node")
                && device.contains("auto: no v4l2loopback")
                && device.contains("PipeWire reachable"),
            "{device}"
        );
        assert!(
            d.log.text().contains("published as a PipeWire camera"),
            "{}",
            d.log.text()
        );
        wait_node(&s, VIEW);
    }
    // No PipeWire for this runtime directory: y4m, and it says why.
    let empty = s.dir.path().join("empty-runtime");
    std::fs::create_dir(&empty).expect("mkdir");
    let mut cmd = SdidCommand::client_of(&s)
        .bus(&s.bus.address)
        .sim()
        .args(["--sink", "auto", "--config", &config])
        .log("info")
        .command();
    cmd.env("XDG_RUNTIME_DIR", &empty)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let _d = Reaped(cmd.spawn().expect("start sdid"));
    let device = wait_for("sdid with the y4m fallback", TIMEOUT, || {
        let out = sdictl(&s.bus.address, &["get", "device"]);
        out.status
            .success()
            .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
    });
    assert!(
        device.contains("sdid-view.y4m")
            && device.contains("auto: no v4l2loopback")
            && device.contains("no PipeWire running for this user"),
        "{device}"
    );
}

#[test]
fn no_signal_card_while_the_source_stops() {
    require_pipewire!();
    let s = Session::start();
    let rec = s.dir.path().join("short.sdirec");
    let rec = rec.to_string_lossy().into_owned();
    {
        let d = Sdid::start(&s, &["--sink", "pipewire"]);
        d.ctl(&["record", &rec, "--seconds", "1"]);
    }
    // The recording played once (no --loop): then the source has stopped and
    // sdid shows the "no signal" card, about 5 times a second.
    let d = Sdid::start(&s, &["--sink", "pipewire", "--replay", &rec]);
    wait_for("the replay to end", TIMEOUT, || {
        d.log.text().contains("showing no-signal").then_some(())
    });
    let rgb_bytes = VIEW_W * VIEW_H * 3;
    let rgb = s.read_frames(VIEW, "video/x-raw,format=RGB", 5, TIMEOUT);
    assert_eq!(rgb.len(), 5 * rgb_bytes);
    let card = no_signal_rgb();
    // A checkerboard of 40 and 72 with a bar of 200 across the middle.
    assert_eq!(&card[..3], &[40, 40, 40]);
    assert_eq!(&card[(VIEW_H / 2 * VIEW_W) * 3..][..3], &[200, 200, 200]);
    for (i, frame) in rgb.chunks_exact(rgb_bytes).enumerate() {
        assert!(
            frame == card.as_slice(),
            "frame {i} is not the no-signal card"
        );
    }
    let crc = frame_crcs(&card, rgb_bytes);
    assert!(d.log.published().iter().any(
        |p| p.get("crc32") == crc.first() && p.get("format").map(String::as_str) == Some("RGB")
    ));
    eprintln!("ok: 5 RGB frames of {VIEW} are the no-signal card while the replay has ended");
}

/// The system service's case (issue 32): sdid without a user session
/// (no XDG_RUNTIME_DIR, systemd's RUNTIME_DIRECTORY) feeds the camera a
/// user's session runs with `--system-feed` (the user unit
/// sdi-pipewire-camera.service): the camera dials sdid's feed socket,
/// publishes sdi-camera with what sdid rendered, follows a mode switch, and
/// keeps its node while sdid restarts. The camera takes frames only from a
/// root server, so this test runs as root (the VM's and CI's user).
#[test]
fn system_feed_camera_gets_the_system_sdids_frames() {
    require_pipewire!();
    if !root_for_the_system_feed() {
        return;
    }
    let s = Session::start();
    let run = tempfile::tempdir().expect("a runtime directory for the system sdid");
    let feed = run
        .path()
        .join(sdi_daemon::sink::pipewire::SYSTEM_FEED_NAME);
    let log = FrameLog::file(s.dir.path().join("sdid.log"));
    let program = sdi_tests::pipewire::camera_program().expect("camera program");
    let _camera = Reaped(
        s.command(&program)
            .arg(sdi_daemon::sink::pipewire::SYSTEM_FEED_FLAG)
            .arg(&feed)
            .env("RUST_LOG", "info,sdid::pipewire::frames=trace")
            .stdout(Stdio::null())
            .stderr(log.writer())
            .spawn()
            .expect("start the camera with --system-feed"),
    );
    let system_sdid = |mode: &str| {
        let child = SdidCommand::new()
            .bus(&s.bus.address)
            .sim()
            .args([
                "--frame-rate-hz",
                "30",
                "--exposure-us",
                "2000",
                "--sink",
                "auto",
            ])
            .args(["--mode", mode])
            .log("info")
            .command()
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("PIPEWIRE_REMOTE")
            .env("RUNTIME_DIRECTORY", run.path())
            .stdout(Stdio::null())
            .stderr(log.writer())
            .spawn()
            .expect("start sdid");
        let child = Reaped(child);
        wait_for("sdid on the bus", TIMEOUT, || {
            sdictl(&s.bus.address, &["get", "mode"])
                .status
                .success()
                .then_some(())
        });
        Sdid {
            _child: child,
            log: log.clone(),
            address: s.bus.address.clone(),
        }
    };
    let d = system_sdid("raw");
    let device = d.ctl(&["get", "device"]);
    assert!(device.contains("camera-feed.sock"), "{device}");
    let view = wait_node(&s, VIEW);
    assert_eq!(prop(&view, "media.role"), "Camera", "{view:?}");
    let rgb_bytes = VIEW_W * VIEW_H * 3;
    let rgb = s.read_frames(VIEW, "video/x-raw,format=RGB", 30, TIMEOUT);
    check_published(&d, crcs_of(&rgb, rgb_bytes), VIEW, "RGB", "raw");
    d.ctl(&["set-mode", "depth-edge"]);
    wait_for("the node description to follow the mode", TIMEOUT, || {
        s.node(VIEW)
            .filter(|p| prop(p, "node.description") == "SDI camera (depth-edge)")
    });
    let yuyv = s.read_frames(VIEW, "video/x-raw,format=YUY2", 30, TIMEOUT);
    check_published(
        &d,
        crcs_of(&yuyv, VIEW_W * VIEW_H * 2),
        VIEW,
        "YUYV",
        "depth-edge",
    );

    // The system sdid restarts: the node stays, and the camera dials again.
    drop(d);
    std::thread::sleep(Duration::from_secs(1));
    assert!(
        s.node(VIEW).is_some(),
        "the node went away with the system sdid"
    );
    let d = system_sdid("bipolar-colour");
    wait_for("the node to follow the new system sdid", TIMEOUT, || {
        s.node(VIEW)
            .filter(|p| prop(p, "node.description") == "SDI camera (bipolar-colour)")
    });
    let rgb = s.read_frames(VIEW, "video/x-raw,format=RGB", 30, TIMEOUT);
    check_published(&d, crcs_of(&rgb, rgb_bytes), VIEW, "RGB", "bipolar-colour");
    eprintln!("ok: the --system-feed camera took the system sdid's frames across a restart");
}

/// Two cameras (`--cameras 2 --sink pipewire`): a camera process each, its
/// nodes named by its serial; each node carries its own camera's frames
/// (the CRC-32s its process logged for that node), and a mode switch on
/// `sim-1` changes only `sim-1`'s description and frames.
#[test]
fn each_of_two_cameras_has_its_own_pipewire_nodes() {
    require_pipewire!();
    let s = Session::start();
    let log = FrameLog::file(s.dir.path().join("sdid.log"));
    let child = SdidCommand::client_of(&s)
        .bus(&s.bus.address)
        .sim()
        .args(["--frame-rate-hz", "30", "--exposure-us", "2000"])
        .args(["--cameras", "2", "--sink", "pipewire"])
        .log("info,sdid::pipewire::frames=trace")
        .command()
        .stdout(Stdio::null())
        .stderr(log.writer())
        .spawn()
        .expect("start sdid");
    let d = Sdid {
        _child: Reaped(child),
        log,
        address: s.bus.address.clone(),
    };
    d.wait_for_cameras(&["sim-0", "sim-1"]);
    let names = |serial: &str| (format!("{VIEW}-{serial}"), format!("{DATA}-{serial}"));
    let rgb_bytes = VIEW_W * VIEW_H * 3;
    let mut first = Vec::new();
    for serial in ["sim-0", "sim-1"] {
        let (view_node, data_node) = names(serial);
        let view = wait_node(&s, &view_node);
        assert_eq!(prop(&view, "media.role"), "Camera", "{view:?}");
        assert_eq!(
            prop(&view, "node.description"),
            format!("SDI camera {serial} (raw)")
        );
        let data = wait_node(&s, &data_node);
        assert_ne!(prop(&data, "media.role"), "Camera", "{data:?}");
        let device = d.ctl(&["--camera", serial, "get", "device"]);
        assert!(device.contains(&format!("\"{view_node}\"")), "{device}");
        let rgb = s.read_frames(&view_node, "video/x-raw,format=RGB", 30, TIMEOUT);
        first.push(check_published(
            &d,
            crcs_of(&rgb, rgb_bytes),
            &view_node,
            "RGB",
            "raw",
        ));
        let y16 = s.read_frames(&data_node, "video/x-raw,format=GRAY16_LE", 30, TIMEOUT);
        check_published(
            &d,
            crcs_of(&y16, SENSOR_W * SENSOR_H * 2),
            &data_node,
            "Y16",
            "raw",
        );
    }
    assert!(
        first[0].iter().all(|c| !first[1].contains(c)),
        "the two cameras' nodes carried the same frames"
    );
    assert!(
        s.node(VIEW).is_none(),
        "a lone camera's node beside two cameras"
    );

    d.ctl(&["--camera", "sim-1", "set-mode", "depth-edge"]);
    let (view0, _) = names("sim-0");
    let (view1, _) = names("sim-1");
    wait_for("sim-1's description to follow its mode", TIMEOUT, || {
        s.node(&view1)
            .filter(|p| prop(p, "node.description") == "SDI camera sim-1 (depth-edge)")
    });
    let yuyv = s.read_frames(&view1, "video/x-raw,format=YUY2", 30, TIMEOUT);
    check_published(
        &d,
        crcs_of(&yuyv, VIEW_W * VIEW_H * 2),
        &view1,
        "YUYV",
        "depth-edge",
    );
    let view = s.node(&view0).expect("sim-0's node");
    assert_eq!(prop(&view, "node.description"), "SDI camera sim-0 (raw)");
    let rgb = s.read_frames(&view0, "video/x-raw,format=RGB", 30, TIMEOUT);
    check_published(&d, crcs_of(&rgb, rgb_bytes), &view0, "RGB", "raw");
    assert_eq!(d.ctl(&["--camera", "sim-0", "get", "mode"]).trim(), "raw");
    eprintln!(
        "ok: two cameras, two node pairs named by serial; a mode switch on sim-1 left sim-0 alone"
    );
}

/// Whether this test runs as root, as the system feed's tests must (the
/// camera takes frames only from a root server); a skip line if not.
fn root_for_the_system_feed() -> bool {
    let root = nix::unistd::getuid().is_root();
    if !root {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_VM",
            format_args!(
                "the system feed test needs root: the camera takes frames only from a root server"
            ),
        );
    }
    root
}

/// The system service with two cameras: a feed socket each
/// (`camera-feed-SERIAL.sock`), and one `--system-feed DIR` camera program
/// serving both, each camera's nodes named by its serial and fed its own
/// frames.
#[test]
fn system_feed_serves_every_cameras_feed_socket() {
    require_pipewire!();
    if !root_for_the_system_feed() {
        return;
    }
    let s = Session::start();
    let run = tempfile::tempdir().expect("a runtime directory for the system sdid");
    let log = FrameLog::file(s.dir.path().join("sdid.log"));
    let program = sdi_tests::pipewire::camera_program().expect("camera program");
    let _camera = Reaped(
        s.command(&program)
            .arg(sdi_daemon::sink::pipewire::SYSTEM_FEED_FLAG)
            .arg(run.path())
            .env("RUST_LOG", "info,sdid::pipewire::frames=trace")
            .stdout(Stdio::null())
            .stderr(log.writer())
            .spawn()
            .expect("start the camera with --system-feed DIR"),
    );
    let child = SdidCommand::new()
        .bus(&s.bus.address)
        .sim()
        .args(["--frame-rate-hz", "30", "--exposure-us", "2000"])
        .args(["--cameras", "2", "--sink", "auto"])
        .log("info")
        .command()
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("PIPEWIRE_REMOTE")
        .env("RUNTIME_DIRECTORY", run.path())
        .stdout(Stdio::null())
        .stderr(log.writer())
        .spawn()
        .expect("start sdid");
    let d = Sdid {
        _child: Reaped(child),
        log,
        address: s.bus.address.clone(),
    };
    d.wait_for_cameras(&["sim-0", "sim-1"]);
    d.ctl(&["--camera", "sim-1", "set-mode", "depth-edge"]);
    let rgb_bytes = VIEW_W * VIEW_H * 3;
    for (serial, mode) in [("sim-0", "raw"), ("sim-1", "depth-edge")] {
        let device = d.ctl(&["--camera", serial, "get", "device"]);
        assert!(
            device.contains(&format!("camera-feed-{serial}.sock")),
            "{device}"
        );
        let view_node = format!("{VIEW}-{serial}");
        wait_for(
            "the description to follow the camera's mode",
            TIMEOUT,
            || {
                s.node(&view_node).filter(|p| {
                    prop(p, "node.description") == format!("SDI camera {serial} ({mode})")
                })
            },
        );
        let rgb = s.read_frames(&view_node, "video/x-raw,format=RGB", 30, TIMEOUT);
        check_published(&d, crcs_of(&rgb, rgb_bytes), &view_node, "RGB", mode);
    }
    assert!(
        s.node(VIEW).is_none(),
        "a lone camera's node beside two cameras"
    );
    eprintln!("ok: one --system-feed DIR camera program served both cameras' feed sockets");
}
