//! Two emulated boards with different serials on dummy_hcd's two UDCs,
//! one sdid (`backend = "opt8241"`, no `[board] serial`): each board is a
//! camera of its serial, with its own `[camera."SERIAL"]` section, mode and
//! FIFO; unplugging and replugging one costs the other no frame (its
//! frame stream's sequence numbers stay consecutive), and the replugged
//! board comes back to the same camera with its settings. A board plugged
//! in after start becomes a new camera the same way, while the first
//! streams on.

use std::io::Read;
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use sdi_api::cameras;
use sdi_api::frame_stream::{FrameHeader, HEADER_BYTES};
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::dbus::{runtime, sdictl, Bus, Daemon};
use sdi_tests::process::Reaped;
use sdi_tests::wait::wait_until;
use zbus::zvariant::Fd;

const A: &str = "EMUA0001";
const B: &str = "EMUB0002";

fn ctl(bus: &Bus, args: &[&str]) -> String {
    sdi_tests::dbus::sdictl_ok(&bus.address, args)
}

/// The sequence numbers of every frame on `stream`, as they come.
fn read_sequences(mut stream: UnixStream, seen: Arc<Mutex<Vec<(u64, u64)>>>) {
    let mut head = [0u8; HEADER_BYTES];
    let mut body = Vec::new();
    while stream.read_exact(&mut head).is_ok() {
        let Ok(h) = FrameHeader::decode(&head) else {
            return;
        };
        body.resize(h.body_bytes(), 0);
        if stream.read_exact(&mut body).is_err() {
            return;
        }
        seen.lock().unwrap().push((h.sequence, h.dropped));
    }
}

fn config(dir: &Path) -> std::path::PathBuf {
    let p = dir.join("sdid.toml");
    std::fs::write(
        &p,
        format!(
            "backend = \"opt8241\"\nmode = \"raw\"\nframe_rate_hz = 30.0\n\
             [board]\non_unplug = \"no-signal\"\nroi = [0, 0, 64, 48]\n\
             [camera.\"{B}\"]\ncolormap = \"grey\"\n"
        ),
    )
    .unwrap();
    p
}

#[test]
fn two_boards_are_two_cameras_and_one_replugged_costs_the_other_nothing() {
    if crate::GUEST.on_host() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let a = BoardEmulator::start("sdia", A).expect("gadget A");
    let b = BoardEmulator::start("sdib", B).expect("gadget B");
    wait_until("both boards enumerated", Duration::from_secs(30), || {
        sdi_daemon::backend::board::attached_serials().is_ok_and(|s| s.len() == 2)
    });
    let bus = Bus::start();
    let _sdid = start_sdid(&bus, tmp.path());
    wait_until("sdid serves both boards", Duration::from_secs(90), || {
        sdictl(&bus.address, &["--camera", B, "get", "mode"])
            .status
            .success()
    });

    // Each board a camera of its serial, in serial order, with its section.
    let list: serde_json::Value = serde_json::from_str(&ctl(&bus, &["--json", "list"])).unwrap();
    let serials: Vec<_> = list["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["serial"].as_str().unwrap().to_owned())
        .collect();
    assert_eq!(serials, [A, B], "{list}");
    assert_eq!(ctl(&bus, &["--camera", A, "get", "colormap"]), "diverging");
    assert_eq!(ctl(&bus, &["--camera", B, "get", "colormap"]), "grey");
    for s in [A, B] {
        let device = ctl(&bus, &["--camera", s, "get", "device"]);
        assert!(device.contains(&format!("serial {s}")), "{device}");
        assert!(device.ends_with(&format!("view-{s}.y4m")), "{device}");
    }

    // Set-mode on one leaves the other.
    ctl(&bus, &["--camera", B, "set-mode", "depth-edge"]);
    assert_eq!(ctl(&bus, &["--camera", A, "get", "mode"]), "raw");
    assert_eq!(ctl(&bus, &["--camera", B, "get", "mode"]), "depth-edge");

    // A's frames, by sequence number, while B goes and comes back.
    let frames_of_a = Sequences::follow(&bus, A);
    let count = || frames_of_a.count();
    wait_until("A's first frames", Duration::from_secs(30), || {
        count() >= 10
    });
    let available = |s: &str| available(&bus, s);
    b.unplug().expect("unplug B");
    wait_until("B missing", Duration::from_secs(30), || !available(B));
    let during = count();
    wait_until("A streams on", Duration::from_secs(30), || {
        count() >= during + 30
    });
    assert!(available(A), "A stayed available");
    b.plug().expect("replug B");
    wait_until("B back", Duration::from_secs(60), || available(B));
    let after = count();
    wait_until("A streams after", Duration::from_secs(30), || {
        count() >= after + 10
    });

    // No frame of A lost: consecutive sequence numbers, none dropped.
    frames_of_a.assert_none_lost();
    // B came back to its camera with its settings.
    assert_eq!(ctl(&bus, &["--camera", B, "get", "mode"]), "depth-edge");
    assert_eq!(ctl(&bus, &["--camera", B, "get", "colormap"]), "grey");
    let list: serde_json::Value = serde_json::from_str(&ctl(&bus, &["--json", "list"])).unwrap();
    assert_eq!(list["cameras"][1]["serial"], B, "{list}");
    assert_eq!(list["cameras"][1]["path"], "/org/sdi/Camera1", "{list}");
    drop(frames_of_a);
    drop(a);
    drop(b);
}

/// One camera's frame stream, read on a thread: each frame's sequence
/// number and the stream's drop count.
struct Sequences {
    seen: Arc<Mutex<Vec<(u64, u64)>>>,
    /// Holds the stream's slot (sdid ends the stream when it leaves).
    _conn: zbus::Connection,
}

impl Sequences {
    fn follow(bus: &Bus, serial: &str) -> Self {
        let (conn, stream) = runtime().block_on(async {
            let conn = sdi_tests::dbus::connect(&bus.address).await;
            let listed = cameras::list(&conn).await.expect("list");
            let path = cameras::choose(&listed, Some(serial))
                .expect("camera")
                .path
                .clone();
            let cam = cameras::proxy(&conn, path, zbus::proxy::CacheProperties::No)
                .await
                .expect("proxy");
            let (ours, theirs) = UnixStream::pair().unwrap();
            cam.stream_frames(Fd::from(&theirs))
                .await
                .expect("StreamFrames");
            (conn, ours)
        });
        let seen = Arc::new(Mutex::new(Vec::new()));
        let reading = seen.clone();
        std::thread::spawn(move || read_sequences(stream, reading));
        Self { seen, _conn: conn }
    }

    fn count(&self) -> usize {
        self.seen.lock().unwrap().len()
    }

    fn assert_none_lost(&self) {
        let frames = self.seen.lock().unwrap().clone();
        for w in frames.windows(2) {
            assert_eq!(w[1].0, w[0].0 + 1, "the sequence jumped: {w:?}");
        }
        assert!(frames.iter().all(|f| f.1 == 0), "the stream dropped frames");
    }
}

fn available(bus: &Bus, serial: &str) -> bool {
    let v: serde_json::Value =
        serde_json::from_str(&ctl(bus, &["--json", "--camera", serial, "get", "stats"])).unwrap();
    v["Stats"]["device_available"].as_bool().unwrap_or(false)
}

fn start_sdid(bus: &Bus, dir: &Path) -> Reaped {
    Reaped(
        Daemon::bare_command(bus, &[])
            .args(["--sink", "y4m", "--y4m-path"])
            .arg(dir.join("view.y4m"))
            .arg("--config")
            .arg(config(dir))
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .spawn()
            .expect("start sdid"),
    )
}

#[test]
fn a_board_plugged_in_later_is_a_new_camera_and_costs_the_first_nothing() {
    if crate::GUEST.on_host() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let a = BoardEmulator::start("sdia", A).expect("gadget A");
    wait_until("A enumerated", Duration::from_secs(30), || {
        sdi_daemon::backend::board::attached_serials().is_ok_and(|s| s.len() == 1)
    });
    let bus = Bus::start();
    let _sdid = start_sdid(&bus, tmp.path());
    wait_until("sdid serves A", Duration::from_secs(90), || {
        sdictl(&bus.address, &["get", "serial"]).status.success()
    });
    // Alone, A's outputs are the configuration's own.
    let device = ctl(&bus, &["get", "device"]);
    assert!(device.ends_with("/view.y4m"), "{device}");
    let frames_of_a = Sequences::follow(&bus, A);
    wait_until("A's first frames", Duration::from_secs(30), || {
        frames_of_a.count() >= 10
    });

    let b = BoardEmulator::start("sdib", B).expect("gadget B");
    wait_until("B is a camera", Duration::from_secs(60), || {
        sdictl(&bus.address, &["--camera", B, "get", "serial"])
            .status
            .success()
    });
    wait_until("B streams", Duration::from_secs(60), || available(&bus, B));
    let list: serde_json::Value = serde_json::from_str(&ctl(&bus, &["--json", "list"])).unwrap();
    assert_eq!(list["cameras"][0]["serial"], A, "{list}");
    assert_eq!(list["cameras"][1]["serial"], B, "{list}");
    assert_eq!(list["cameras"][1]["path"], "/org/sdi/Camera1", "{list}");
    // B's section and its own FIFO; A untouched.
    assert_eq!(ctl(&bus, &["--camera", B, "get", "colormap"]), "grey");
    let device = ctl(&bus, &["--camera", B, "get", "device"]);
    assert!(device.ends_with(&format!("view-{B}.y4m")), "{device}");
    ctl(&bus, &["--camera", B, "set-mode", "depth-edge"]);
    assert_eq!(ctl(&bus, &["--camera", A, "get", "mode"]), "raw");
    let after = frames_of_a.count();
    wait_until("A streams on", Duration::from_secs(30), || {
        frames_of_a.count() >= after + 10
    });
    frames_of_a.assert_none_lost();
    // Two now: sdictl asks which.
    let out = sdictl(&bus.address, &["get", "mode"]);
    assert_eq!(out.status.code(), Some(2));
    drop(frames_of_a);
    drop(b);
    drop(a);
}

#[test]
fn a_board_with_an_odd_serial_is_named_safely() {
    if crate::GUEST.on_host() {
        return;
    }
    // A device chooses its serial: this one could not name a file.
    let odd = BoardEmulator::start("sdiodd", "../x y").expect("gadget");
    wait_until("enumerated", Duration::from_secs(30), || {
        sdi_daemon::backend::board::attached_serials().is_ok_and(|s| s.len() == 1)
    });
    let tmp = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    let _sdid = start_sdid(&bus, tmp.path());
    wait_until("sdid serves the board", Duration::from_secs(90), || {
        sdictl(&bus.address, &["get", "mode"]).status.success()
    });
    assert_eq!(ctl(&bus, &["get", "serial"]), ".._x_y");
    let list: serde_json::Value = serde_json::from_str(&ctl(&bus, &["--json", "list"])).unwrap();
    assert_eq!(list["cameras"][0]["serial"], ".._x_y", "{list}");
    // Its outputs keep the configured names (not the serial's).
    let device = ctl(&bus, &["get", "device"]);
    assert!(device.ends_with("/view.y4m"), "{device}");
    assert_eq!(ctl(&bus, &["--camera", ".._x_y", "get", "mode"]), "raw");
    drop(odd);
}

#[test]
fn a_board_that_cannot_be_opened_costs_the_others_nothing() {
    use sdi_tests::board_emulator::hostile::{HostileBoard, HostileMode};
    if crate::GUEST.on_host() {
        return;
    }
    let a = BoardEmulator::start("sdia", A).expect("gadget A");
    // The board's IDs, but no bulk IN endpoint: it cannot be opened.
    let bad = HostileBoard::start("sdibad", "BAD00001", HostileMode::GarbageDescriptors)
        .expect("hostile gadget");
    wait_until("both enumerated", Duration::from_secs(30), || {
        sdi_daemon::backend::board::attached_serials().is_ok_and(|s| s.len() == 2)
    });
    let tmp = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    let _sdid = start_sdid(&bus, tmp.path());
    wait_until("sdid serves A", Duration::from_secs(90), || {
        sdictl(&bus.address, &["--camera", A, "get", "mode"])
            .status
            .success()
    });
    let list: serde_json::Value = serde_json::from_str(&ctl(&bus, &["--json", "list"])).unwrap();
    let cameras = list["cameras"].as_array().unwrap();
    assert_eq!(cameras.len(), 1, "{list}");
    assert_eq!(cameras[0]["serial"], A, "{list}");
    wait_until("A streams", Duration::from_secs(30), || available(&bus, A));
    // The only camera served: plain sdictl reaches it.
    assert_eq!(ctl(&bus, &["get", "serial"]), A);
    drop(bad);
    drop(a);
}
