//! PipeWire (with WirePlumber) sees the SDI view node, in the VM, in both
//! start orders: `pw-dump` lists it as `Video/Source` with `media.role =
//! Camera`. Reading frames with `gst-launch-1.0 pipewiresrc` through
//! PipeWire 0.3.65 does not work on v4l2loopback 0.12.7 nor 0.15
//! (docs/loopback.md): 0.12.7's QUERYBUF reports every buffer queued, and
//! PipeWire before 1.3.81 cannot hand another process the buffers of a
//! v4l2 device without VIDIOC_EXPBUF, which no v4l2loopback has (the link
//! to pipewiresrc allows only DmaBuf/MemFd; with one buffer the client
//! node refuses the mapped pointer). `SDI_PIPEWIRE_READ=0.12` (or `0.15`)
//! tries it and asserts frames of the current mode (mean colour against
//! `sdictl snapshot`, black letterbox bars, a mode switch), reading with
//! `max-buffers=10` (pipewiresrc asks 16 by default, more than the node's
//! `max_buffers=10`); with these versions it fails.
//!
//! PipeWire's v4l2 monitor probes a node on its udev event and creates a
//! `Video/Source` only for a device that offers CAPTURE then; with
//! exclusive_caps=1 the view node is a capture device only once sdid
//! streams. So:
//! * sdid first: WirePlumber's first probe finds a capture device;
//! * WirePlumber first: the node stays invisible (checked) until a udev
//!   change event, which `sdid.service` sends once sdid is ready
//!   (`ExecStartPost=+udevadm trigger --action=change ...`, after the sink
//!   streams: sdid takes its bus name only then). The test runs that very
//!   command line from the unit file.
//!
//! systemd-udevd runs in the guest (PipeWire listens to udev, not to the
//! kernel); PipeWire and WirePlumber run as root in the harness's
//! `pipewire::Session` (a private session bus), in root's runtime directory.

use std::path::Path;
use std::time::{Duration, Instant};

use serde_json::Value;

use sdi_tests::capture;
use sdi_tests::clients::{self, mean_rgb, off_by, Sdid, PMD};
use sdi_tests::loopback::{self, ModuleBuild};
use sdi_tests::pipewire::{frame_crcs, FrameLog, Session, SessionOptions};
use sdi_tests::process::{repo_root, stdout_of};
use sdi_tests::udev::{self, udevadm};
use sdi_tests::wait::wait_until;

/// Buffers pipewiresrc may ask for: PipeWire's v4l2 source requests as
/// many buffers as the link negotiated and fails ("can't allocate enough
/// buffers (10 < 16)") when the driver grants fewer; pipewiresrc asks 16 by
/// default, the node has `max_buffers=10`.
const READ_BUFFERS: u32 = 10;
/// One 640x480 RGB frame.
const FRAME_RGB: usize = 640 * 480 * 3;
/// videoconvert's YUY2 to RGB against sdid's rendering: codes of tolerance
/// on a channel's mean.
const TOLERANCE: f64 = 12.0;
const VIEW_NR: u32 = 40;
const DATA_NR: u32 = 41;

/// Waits until udevd has processed the SDI nodes' add events.
fn nodes_initialized() {
    let view = format!("/dev/video{VIEW_NR}");
    let data = format!("/dev/video{DATA_NR}");
    udev::wait_initialized(&[Path::new(&view), Path::new(&data)]);
}

/// The `udevadm trigger` line of `sdid.service`'s ExecStartPost.
fn unit_trigger() -> Vec<String> {
    let unit = std::fs::read_to_string(repo_root().join("udev/systemd/sdid.service.in"))
        .expect("read sdid.service.in");
    let line = unit
        .lines()
        .find_map(|l| l.strip_prefix("ExecStartPost="))
        .expect("sdid.service.in has an ExecStartPost");
    let line = line.trim_start_matches(['+', '-', '@', '!', ':']);
    assert!(line.contains("udevadm trigger"), "{line}");
    line.split_whitespace().map(str::to_owned).collect()
}

/// Runs sdid.service's ExecStartPost (udevadm trigger --action=change ...),
/// returning once udevd has processed the events it caused.
fn trigger() -> Vec<String> {
    let trigger = unit_trigger();
    let args: Vec<&str> = trigger[2..].iter().map(String::as_str).collect();
    assert_eq!(trigger[1], "trigger", "{trigger:?}");
    udev::trigger_settled(&args);
    trigger
}

/// Where the session's PipeWire runs (root's runtime directory): sdid's
/// PipeWire camera, started before the session in one order, waits for the
/// daemon's socket there.
const RUNTIME: &str = "/run/user/0";

/// A PipeWire + WirePlumber session of this test (`sdi_tests::pipewire`),
/// in [`RUNTIME`], with WirePlumber's user configuration `config_home` when
/// given; returned once WirePlumber is up.
fn start_session(config_home: Option<&Path>) -> Session {
    let pw = Session::start_with(SessionOptions {
        runtime_dir: Some(Path::new(RUNTIME)),
        config_home,
    });
    if !pw.wait_wireplumber(Duration::from_secs(120)) {
        diagnose(&pw);
        panic!("WirePlumber did not connect to PipeWire in 120 s");
    }
    pw
}

/// The SDI camera's node: (id, props), if PipeWire lists it.
fn sdi_node(pw: &Session) -> Option<(u64, Value)> {
    pw.objects().into_iter().find_map(|o| {
        let p = &o["info"]["props"];
        let name = ["node.description", "node.nick", "api.v4l2.cap.card"]
            .iter()
            .find_map(|k| p[*k].as_str())
            .unwrap_or("");
        (p["media.class"] == "Video/Source" && name.contains(clients::VIEW_LABEL))
            .then(|| (o["id"].as_u64().unwrap_or(0), p.clone()))
    })
}

/// Reads 8 frames of the node of serial `serial` with pipewiresrc
/// (at most `READ_BUFFERS` buffers); returns the last frame as RGB and
/// the seconds from gst-launch's start to its end of stream.
fn read_view(pw: &Session, serial: &str) -> (Vec<u8>, f64) {
    let file = "/tmp/pw-view.rgb";
    let _ = std::fs::remove_file(file);
    let t0 = Instant::now();
    let pipeline = format!(
        "pipewiresrc target-object={serial} max-buffers={READ_BUFFERS} always-copy=true num-buffers=8 \
         ! video/x-raw,format=YUY2,width=640,height=480 \
         ! videoconvert ! video/x-raw,format=RGB ! filesink location={file}"
    );
    let out = pw
        .command("timeout")
        .args(["120", "gst-launch-1.0"])
        .args(pipeline.split_whitespace())
        .output()
        .expect("gst-launch-1.0");
    let secs = t0.elapsed().as_secs_f64();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    if !out.status.success() {
        diagnose(pw);
        panic!("{pipeline}: {}\n{log}", out.status);
    }
    let bytes = std::fs::read(file).expect("frames");
    assert_eq!(bytes.len() % FRAME_RGB, 0, "whole frames: {log}");
    assert_eq!(bytes.len() / FRAME_RGB, 8, "8 frames: {log}");
    (bytes[bytes.len() - FRAME_RGB..].to_vec(), secs)
}

/// Prints what PipeWire lists, udev's view of the node and the daemons' logs.
fn diagnose(pw: &Session) {
    for o in pw.objects() {
        let p = &o["info"]["props"];
        eprintln!(
            "pw-dump {} {}: class {} name {} card {} path {}",
            o["id"],
            o["type"],
            p["media.class"],
            p["node.name"],
            p["api.v4l2.cap.card"],
            p["api.v4l2.path"]
        );
    }
    let info = udevadm()
        .args(["info", &format!("/dev/video{VIEW_NR}")])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
        .unwrap_or_default();
    eprintln!("udevadm info:\n{info}");
    for program in ["pipewire", "wireplumber"] {
        let log = pw.log_path(program);
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        eprintln!(
            "{}:\n{}",
            log.display(),
            lines[lines.len().saturating_sub(80)..].join("\n")
        );
    }
}

/// Waits for PipeWire to list the SDI camera; on timeout prints what it
/// lists, udev's view of the node and the daemons' logs, then panics.
fn wait_listed(pw: &Session, what: &str) -> Duration {
    let t0 = Instant::now();
    while sdi_node(pw).is_none() {
        if t0.elapsed() > Duration::from_secs(60) {
            diagnose(pw);
            panic!("{what}: PipeWire does not list the SDI camera after 60 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    t0.elapsed()
}

/// The node's properties, then frames of the current mode read through
/// PipeWire: the mean colour of the mode (`sdictl snapshot`), black
/// letterbox bars, and a mode switch seen.
fn check(pw: &Session, sdid: &Sdid, order: &str, read: bool) {
    let (id, props) = sdi_node(pw).expect("listed");
    assert_eq!(props["media.role"], "Camera", "{order}: {props}");
    let serial = props["object.serial"].to_string();
    eprintln!(
        "{order}: PipeWire node {id} (serial {serial}): {} ({})",
        props["node.description"], props["media.class"]
    );
    // Without SDI's WirePlumber rule: doctor says this node cannot be read
    // (PipeWire 0.3.65) and names the rule.
    let doctor = doctor_pipewire(pw, sdid);
    assert!(
        doctor.iter().any(|(id, st, sum, fix)| id == "pw-node"
            && st == "warn"
            && sum.contains("v4l2loopback node")
            && sum.contains("cannot be read")
            && fix.contains("51-sdi-v4l2")),
        "{order}: doctor: {doctor:?}"
    );
    if !read {
        return;
    }
    for (i, mode) in ["raw", "separation"].into_iter().enumerate() {
        sdid.set_mode(mode);
        let expected = sdid.expected_view_mean();
        let (frame, secs) = read_view(pw, &serial);
        let mean = mean_rgb(&frame);
        let top = mean_rgb(&frame[..640 * 3 * 4]);
        eprintln!(
            "{order}: pipewiresrc, {mode}: 8 frames in {secs:.1} s (start to EOS{}), \
             mean {mean:.1?} (expected {expected:.1?}), top rows {top:.1?}",
            if i == 0 { "; time to first frame" } else { "" }
        );
        assert!(
            off_by(mean, expected) < TOLERANCE,
            "{order}: {mode} frame through PipeWire {mean:?}, expected {expected:?}"
        );
        assert!(
            top.iter().all(|&c| c < TOLERANCE),
            "{order}: letterbox bar not black: {top:?}"
        );
    }
}

/// Both start orders on module `build`; with `read`, frames through
/// PipeWire are asserted in each.
fn both_orders(build: ModuleBuild, read: bool) {
    eprintln!("== {build}");
    // Order 1: sdid first, then PipeWire and WirePlumber.
    clients::load_module_build(build, VIEW_NR, DATA_NR);
    nodes_initialized();
    let sdid = Sdid::start(VIEW_NR, DATA_NR, PMD, 15);
    // udev recorded the node as output-only at module load (v4l_id's
    // ID_V4L_CAPABILITIES); sdid.service's change event updates it.
    trigger();
    let t0 = Instant::now();
    let pw = start_session(None);
    let t = wait_listed(&pw, "sdid first");
    eprintln!(
        "sdid first: listed {:.1} s after PipeWire started ({:.1} s for WirePlumber)",
        t0.elapsed().as_secs_f64(),
        t.as_secs_f64()
    );
    check(&pw, &sdid, "sdid first", read);
    drop(pw);
    drop(sdid);

    // Order 2: PipeWire and WirePlumber first, on a fresh node.
    loopback::unload_module().expect("rmmod");
    clients::load_module_build(build, VIEW_NR, DATA_NR);
    nodes_initialized();
    let pw = start_session(None);
    assert!(
        sdi_node(&pw).is_none(),
        "listed before a producer: exclusive_caps=1 should hide it"
    );
    let sdid = Sdid::start(VIEW_NR, DATA_NR, PMD, 15);
    nodes_initialized();
    let hidden = sdi_node(&pw).is_none();
    eprintln!(
        "WirePlumber first: {} once sdid streams, before any udev event",
        if hidden {
            "still not listed"
        } else {
            "already listed"
        }
    );
    // What sdid.service does once sdid is ready.
    let trigger = trigger();
    let t = wait_listed(&pw, "WirePlumber first, after the change event");
    eprintln!(
        "WirePlumber first: listed {:.1} s after {trigger:?}",
        t.as_secs_f64()
    );
    check(&pw, &sdid, "WirePlumber first", read);
    assert!(hidden, "the node was listed without a udev change event: the test no longer shows why sdid.service triggers one");
    drop(pw);
    drop(sdid);
    loopback::unload_module().expect("rmmod");
}

fn in_vm_checks() {
    let _udevd = udev::start_udevd();
    beside_loopback_both_orders();
    // Listed in both orders; reading frames through PipeWire 0.3.65 does
    // not work with v4l2loopback (docs/loopback.md: 0.12.7 reports every
    // buffer queued; no v4l2loopback has VIDIOC_EXPBUF, which PipeWire
    // before 1.3.81 needs to hand a v4l2 buffer to another process), so it
    // is only tried, and must then succeed, with SDI_PIPEWIRE_READ=0.12 or
    // SDI_PIPEWIRE_READ=0.15 (for a newer PipeWire).
    match std::env::var("SDI_PIPEWIRE_READ").as_deref() {
        Ok("0.15") => both_orders(ModuleBuild::V0150, true),
        Ok(_) => both_orders(ModuleBuild::Debian0127, true),
        Err(_) => both_orders(ModuleBuild::Debian0127, false),
    }
}

#[test]
fn vm_pipewire_lists_the_sdi_camera_in_both_orders() {
    if crate::GUEST.on_host() {
        return;
    }
    in_vm_checks();
}

/// One 640x480 YUYV frame.
const FRAME_YUYV: usize = 640 * 480 * 2;

/// SDI's WirePlumber rule (`udev/wireplumber/`, both syntaxes, as the
/// camera package installs them) in a user configuration directory, for
/// `XDG_CONFIG_HOME`.
fn rule_config_home() -> &'static Path {
    let home = Path::new("/tmp/sdi-wireplumber-config");
    let from = repo_root().join("udev/wireplumber");
    for (dir, file) in [
        ("main.lua.d", "51-sdi-v4l2.lua"),
        ("wireplumber.conf.d", "51-sdi-v4l2.conf"),
    ] {
        let to = home.join("wireplumber").join(dir);
        std::fs::create_dir_all(&to).expect("mkdir the WirePlumber config");
        std::fs::copy(from.join(file), to.join(file)).expect("copy the rule");
    }
    home
}

/// What PipeWire lists of SDI: (camera-role nodes naming SDI, v4l2 devices
/// and nodes of SDI's card labels).
fn sdi_listed(pw: &Session) -> (Vec<Value>, Vec<Value>) {
    let labels = [clients::VIEW_LABEL, clients::DATA_LABEL];
    let mut cameras = Vec::new();
    let mut v4l2 = Vec::new();
    for o in pw.objects() {
        let p = &o["info"]["props"];
        let card = ["api.v4l2.cap.card", "device.product.name"]
            .iter()
            .any(|k| p[*k].as_str().is_some_and(|c| labels.contains(&c)));
        if card {
            v4l2.push(p.clone());
        }
        let names_sdi = ["node.name", "node.description", "node.nick"]
            .iter()
            .any(|k| {
                p[*k]
                    .as_str()
                    .is_some_and(|n| n.contains("SDI") || n.starts_with("sdi-"))
            });
        if o["type"] == "PipeWire:Interface:Node" && p["media.role"] == "Camera" && names_sdi {
            cameras.push(p.clone());
        }
    }
    (cameras, v4l2)
}

/// Waits for exactly one SDI camera in PipeWire, the camera process's
/// `sdi-camera` with `media.role = Camera`, and no v4l2 node or device of
/// SDI's labels (the rule keeps them out); returns its properties.
fn one_sdi_camera(pw: &Session, order: &str) -> Value {
    let t0 = Instant::now();
    loop {
        let (cameras, v4l2) = sdi_listed(pw);
        assert!(
            v4l2.is_empty(),
            "{order}: the loopback node is listed despite the rule: {v4l2:?}"
        );
        if let [camera] = cameras.as_slice() {
            assert_eq!(camera["node.name"], "sdi-camera", "{order}: {camera}");
            assert_eq!(camera["media.class"], "Video/Source", "{order}: {camera}");
            return camera.clone();
        }
        assert!(
            cameras.len() < 2,
            "{order}: more than one SDI camera: {cameras:?}"
        );
        if t0.elapsed() > Duration::from_secs(90) {
            diagnose(pw);
            panic!("{order}: PipeWire lists no sdi-camera after 90 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Reads 30 YUYV frames of `sdi-camera` with pipewiresrc; asserts each is
/// one the camera process logged as published in `mode` (CRC-32).
fn read_published(pw: &Session, log: &FrameLog, order: &str, mode: &str) {
    let file = "/tmp/pw-camera.yuyv";
    let _ = std::fs::remove_file(file);
    let pipeline = format!(
        "pipewiresrc target-object=sdi-camera num-buffers=30 \
         ! video/x-raw,format=YUY2,width=640,height=480 ! filesink location={file}"
    );
    let t0 = Instant::now();
    let out = pw
        .command("timeout")
        .args(["180", "gst-launch-1.0", "-q"])
        .args(pipeline.split_whitespace())
        .output()
        .expect("gst-launch-1.0");
    if !out.status.success() {
        diagnose(pw);
        panic!(
            "{order}: {pipeline}: {}\n{}{}\nsdid's log:\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr),
            log.text()
        );
    }
    let bytes = std::fs::read(file).expect("frames");
    assert_eq!(bytes.len(), 30 * FRAME_YUYV, "{order}: 30 whole frames");
    let crcs = frame_crcs(&bytes, FRAME_YUYV);
    let t_read = t0.elapsed();
    log.assert_published(&crcs, "sdi-camera", "YUYV", mode, order);
    let distinct: std::collections::HashSet<&String> = crcs.iter().collect();
    eprintln!(
        "{order}: pipewiresrc read 30 frames of sdi-camera in {:.1} s, all published by sdid in mode {mode} ({} distinct)",
        t_read.as_secs_f64(),
        distinct.len()
    );
}

/// With the module loaded and a PipeWire session, sdid (`--sink auto`)
/// feeds the loopback nodes and the PipeWire camera: PipeWire lists one SDI
/// camera, pipewiresrc reads what sdid published, ffmpeg reads the loopback
/// node, and a mode switch reaches both.
fn check_beside(pw: &Session, sdid: &Sdid, log: &FrameLog, order: &str, modes: &[&str]) {
    let camera = one_sdi_camera(pw, order);
    eprintln!(
        "{order}: PipeWire lists one SDI camera: {} ({})",
        camera["node.description"], camera["media.role"]
    );
    let doctor = doctor_pipewire(pw, sdid);
    assert!(
        doctor.iter().any(|(id, st, sum, _)| id == "pipewire"
            && st == "ok"
            && sum.contains("one SDI camera")),
        "{order}: doctor: {doctor:?}"
    );
    let nodes: Vec<_> = doctor.iter().filter(|c| c.0 == "pw-node").collect();
    assert_eq!(
        nodes.len(),
        2,
        "{order}: the camera's view and data nodes: {doctor:?}"
    );
    assert!(
        nodes
            .iter()
            .all(|c| c.1 == "ok" && c.2.contains("the PipeWire camera")),
        "{order}: doctor: {doctor:?}"
    );
    let status = stdout_of(&sdid.ctl(&["status"]));
    assert!(
        status.contains("sdi-camera"),
        "{order}: the D-Bus device names both sinks: {status}"
    );
    for &mode in modes {
        sdid.set_mode(mode);
        let expected = sdid.expected_view_mean();
        wait_until(
            &format!("{order}: sdi-camera describes mode {mode}"),
            Duration::from_secs(30),
            || one_sdi_camera(pw, order)["node.description"] == format!("SDI camera ({mode})"),
        );
        read_published(pw, log, order, mode);
        let seen = capture::last_frame_mean_rgb(&sdid.view, 640, 480);
        eprintln!("{order}: ffmpeg on the loopback node, {mode}: mean {seen:.1?} (expected {expected:.1?})");
        assert!(
            off_by(seen, expected) < TOLERANCE,
            "{order}: {mode} through the loopback node {seen:?}, expected {expected:?}"
        );
    }
}

/// Issue 32's user session, both start orders, module loaded, SDI's
/// WirePlumber rule installed.
fn beside_loopback_both_orders() {
    let t_phase = Instant::now();
    let config = rule_config_home();
    let log = FrameLog::file(std::path::PathBuf::from("/tmp/sdid-beside.log"));
    let runtime = vec![("XDG_RUNTIME_DIR".to_owned(), RUNTIME.to_owned())];
    std::fs::create_dir_all(RUNTIME).expect("runtime dir");

    // sdid first: its PipeWire camera starts once PipeWire is up.
    clients::load_module(VIEW_NR, DATA_NR);
    nodes_initialized();
    let sdid = Sdid::start_auto(VIEW_NR, DATA_NR, PMD, 15, runtime.clone(), log.path());
    trigger();
    let t0 = Instant::now();
    let pw = start_session(Some(config));
    one_sdi_camera(&pw, "beside, sdid first");
    eprintln!(
        "beside, sdid first: sdi-camera listed {:.1} s after PipeWire started",
        t0.elapsed().as_secs_f64()
    );
    // The mode switch is checked in the other order (VM time).
    check_beside(&pw, &sdid, &log, "beside, sdid first", &["raw"]);
    drop(sdid);
    drop(pw);
    // The camera process ended with its PipeWire connection.
    loopback::unload_module().expect("rmmod");

    // WirePlumber first.
    clients::load_module(VIEW_NR, DATA_NR);
    nodes_initialized();
    let pw = start_session(Some(config));
    let sdid = Sdid::start_auto(VIEW_NR, DATA_NR, PMD, 15, runtime, log.path());
    trigger();
    check_beside(
        &pw,
        &sdid,
        &log,
        "beside, WirePlumber first",
        &["raw", "separation"],
    );
    // Still hidden a while after the udev change event.
    std::thread::sleep(Duration::from_secs(3));
    one_sdi_camera(&pw, "beside, WirePlumber first, 3 s after the change event");
    drop(sdid);
    drop(pw);
    loopback::unload_module().expect("rmmod");
    eprintln!(
        "beside the loopback nodes, both orders: {:.1} s",
        t_phase.elapsed().as_secs_f64()
    );
}

/// `sdictl doctor --json` as the session's user (its PipeWire): the
/// PipeWire checks, (status, summary, fix) by id.
fn doctor_pipewire(pw: &Session, sdid: &Sdid) -> Vec<(String, String, String, String)> {
    let out = pw
        .command(sdi_tests::dbus::bin("sdictl"))
        .args(["--bus-address", &sdid.bus.address, "doctor", "--json"])
        .output()
        .expect("run sdictl doctor");
    let v: Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "doctor --json is not JSON ({e}): {}",
            String::from_utf8_lossy(&out.stdout)
        )
    });
    let checks: Vec<_> = v["checks"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|c| c["id"] == "pipewire" || c["id"] == "pw-node")
        .map(|c| {
            let s = |k: &str| c[k].as_str().unwrap_or_default().to_owned();
            (s("id"), s("status"), s("summary"), s("fix"))
        })
        .collect();
    for (id, status, summary, _) in &checks {
        eprintln!("  doctor [{status}] {id}: {summary}");
    }
    checks
}
