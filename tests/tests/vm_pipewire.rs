//! PipeWire (with WirePlumber) sees the SDI view node, in the VM, in both
//! start orders: `pw-dump` lists it as `Video/Source` with `media.role =
//! Camera`. Reading frames with `gst-launch-1.0 pipewiresrc` does not work
//! in the VM yet ("Failed to set pipeline to PAUSED"); it is tried only with
//! SDI_PIPEWIRE_READ=1 (docs/loopback.md).
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
//! kernel); PipeWire and WirePlumber run as root with their own runtime
//! directory and a private session bus.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use sdi_tests::clients::{self, mean_rgb, wait_until, Sdid, PMD};
use sdi_tests::dbus::Bus;
use sdi_tests::loopback;
use sdi_tests::process::{repo_root, Reaped};
use sdi_tests::udev::{self, udevadm};
use sdi_tests::vm;

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

/// PipeWire + WirePlumber (+ pipewire-pulse not needed), killed on drop.
struct PipeWire {
    _bus: Bus,
    _procs: Vec<Reaped>,
    env: Vec<(String, String)>,
}

impl PipeWire {
    fn start() -> Self {
        let runtime = Path::new("/run/user/0");
        std::fs::create_dir_all(runtime).expect("runtime dir");
        // WirePlumber 0.4 quits ("failed to start systemd logind monitor:
        // -2") when logind's state directories are missing, as in the VM.
        for d in ["seats", "sessions", "users", "machines"] {
            std::fs::create_dir_all(Path::new("/run/systemd").join(d))
                .expect("mkdir /run/systemd/*");
        }
        let bus = Bus::start();
        let env = vec![
            ("XDG_RUNTIME_DIR".to_owned(), runtime.display().to_string()),
            ("DBUS_SESSION_BUS_ADDRESS".to_owned(), bus.address.clone()),
        ];
        let spawn = |prog: &str| {
            let log = std::fs::File::create(format!("/tmp/{prog}.log")).expect("log");
            let mut c = Command::new(prog);
            c.envs(env.iter().map(|(k, v)| (k, v)))
                .env("WIREPLUMBER_DEBUG", "2")
                .stdin(Stdio::null())
                .stdout(log.try_clone().expect("log"))
                .stderr(log);
            Reaped(c.spawn().unwrap_or_else(|e| panic!("spawn {prog}: {e}")))
        };
        let pw = spawn("pipewire");
        wait_until("pipewire's socket", Duration::from_secs(60), || {
            runtime.join("pipewire-0").exists()
        });
        let wp = spawn("wireplumber");
        let me = Self {
            _bus: bus,
            _procs: vec![wp, pw],
            env,
        };
        // WirePlumber is up when it shows as a client.
        let t0 = Instant::now();
        while !me
            .dump()
            .iter()
            .any(|o| o["info"]["props"]["application.name"] == "WirePlumber")
        {
            if t0.elapsed() > Duration::from_secs(120) {
                diagnose(&me);
                panic!("WirePlumber did not connect to PipeWire in 120 s");
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        me
    }

    fn dump(&self) -> Vec<Value> {
        let out = Command::new("pw-dump")
            .envs(self.env.iter().map(|(k, v)| (k, v)))
            .output()
            .expect("pw-dump");
        serde_json::from_slice(&out.stdout).unwrap_or_default()
    }

    /// The SDI camera's node: (id, props), if PipeWire lists it.
    fn sdi_node(&self) -> Option<(u64, Value)> {
        self.dump().into_iter().find_map(|o| {
            let p = &o["info"]["props"];
            let name = ["node.description", "node.nick", "api.v4l2.cap.card"]
                .iter()
                .find_map(|k| p[*k].as_str())
                .unwrap_or("");
            (p["media.class"] == "Video/Source" && name.contains(clients::VIEW_LABEL))
                .then(|| (o["id"].as_u64().unwrap_or(0), p.clone()))
        })
    }

    /// Reads frames of node `id` with pipewiresrc; the last frame as RGB.
    fn read(&self, id: u64) -> (Vec<u8>, f64) {
        let file = "/tmp/pw-view.rgb";
        let _ = std::fs::remove_file(file);
        let t0 = Instant::now();
        let pipeline = format!(
            "pipewiresrc target-object={id} always-copy=true num-buffers=4 ! video/x-raw,format=YUY2,width=640,height=480 \
             ! videoconvert ! video/x-raw,format=RGB ! filesink location={file}"
        );
        let out = Command::new("timeout")
            .args(["120", "gst-launch-1.0", "-v"])
            .args(pipeline.split_whitespace())
            .envs(self.env.iter().map(|(k, v)| (k, v)))
            .env("GST_DEBUG", "pipewire*:4")
            .output()
            .expect("gst-launch-1.0");
        let log = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(out.status.success(), "{pipeline}: {}\n{log}", out.status);
        let bytes = std::fs::read(file).expect("frames");
        assert_eq!(bytes.len() % (640 * 480 * 3), 0, "whole frames");
        assert!(bytes.len() >= 640 * 480 * 3, "no frame: {log}");
        (
            bytes[bytes.len() - 640 * 480 * 3..].to_vec(),
            t0.elapsed().as_secs_f64(),
        )
    }
}

/// Prints what PipeWire lists, udev's view of the node and the daemons' logs.
fn diagnose(pw: &PipeWire) {
    for o in pw.dump() {
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
    for log in ["/tmp/pipewire.log", "/tmp/wireplumber.log"] {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        eprintln!(
            "{log}:\n{}",
            lines[lines.len().saturating_sub(80)..].join("\n")
        );
    }
}

/// Waits for PipeWire to list the SDI camera; on timeout prints what it
/// lists, udev's view of the node and the daemons' logs, then panics.
fn wait_listed(pw: &PipeWire, what: &str) -> Duration {
    let t0 = Instant::now();
    while pw.sdi_node().is_none() {
        if t0.elapsed() > Duration::from_secs(60) {
            diagnose(pw);
            panic!("{what}: PipeWire does not list the SDI camera after 60 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    t0.elapsed()
}

/// The node's properties and a frame with the mode's colours.
fn check(pw: &PipeWire, sdid: &Sdid, order: &str) {
    let (id, props) = pw.sdi_node().expect("listed");
    assert_eq!(props["media.role"], "Camera", "{order}: {props}");
    eprintln!(
        "{order}: PipeWire node {id}: {} ({})",
        props["node.description"], props["media.class"]
    );
    // Reading frames through PipeWire: not yet working in the VM
    // (docs/loopback.md); tried and reported, not asserted.
    if std::env::var_os("SDI_PIPEWIRE_READ").is_some() {
        sdid.set_mode("raw");
        let (frame, secs) = pw.read(id);
        eprintln!(
            "{order}: pipewiresrc read in {secs:.1} s, mean {:.1?}",
            mean_rgb(&frame)
        );
    }
}

fn in_vm_checks() {
    let _udevd = udev::start_udevd();

    // Order 1: sdid first, then PipeWire and WirePlumber.
    clients::load_module(VIEW_NR, DATA_NR);
    nodes_initialized();
    let sdid = Sdid::start(VIEW_NR, DATA_NR, PMD, 15);
    // udev recorded the node as output-only at module load (v4l_id's
    // ID_V4L_CAPABILITIES); sdid.service's change event updates it.
    trigger();
    let t0 = Instant::now();
    let pw = PipeWire::start();
    let t = wait_listed(&pw, "sdid first");
    eprintln!(
        "sdid first: listed {:.1} s after PipeWire started ({:.1} s for WirePlumber)",
        t0.elapsed().as_secs_f64(),
        t.as_secs_f64()
    );
    check(&pw, &sdid, "sdid first");
    drop(pw);
    drop(sdid);

    // Order 2: PipeWire and WirePlumber first, on a fresh node.
    loopback::unload_module().expect("rmmod");
    clients::load_module(VIEW_NR, DATA_NR);
    nodes_initialized();
    let pw = PipeWire::start();
    assert!(
        pw.sdi_node().is_none(),
        "listed before a producer: exclusive_caps=1 should hide it"
    );
    let sdid = Sdid::start(VIEW_NR, DATA_NR, PMD, 15);
    nodes_initialized();
    let hidden = pw.sdi_node().is_none();
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
    check(&pw, &sdid, "WirePlumber first");
    assert!(hidden, "the node was listed without a udev change event: the test no longer shows why sdid.service triggers one");
}

#[test]
fn vm_pipewire_lists_the_sdi_camera_in_both_orders() {
    if !vm::in_vm() {
        clients::export_binaries();
        vm::run_test_in_vm("vm_pipewire_lists_the_sdi_camera_in_both_orders", 600);
        return;
    }
    in_vm_checks();
}
