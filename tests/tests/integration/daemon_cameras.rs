//! Several cameras in one sdid (`--backend sim --cameras 2`): each its own
//! object (listed by the object manager, named by serial), settings,
//! `[camera."SERIAL"]` section and y4m FIFO; `sdictl --camera` reaches
//! one, and without it sdictl refuses to guess.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::Duration;

use sdi_tests::dbus::{sdictl, Bus, Daemon};
use sdi_tests::require_dbus;
use sdi_tests::sdid_command::SdidCommand;
use sdi_tests::wait::wait_until;

use crate::view_page::View;

/// sdid with two simulated cameras, its FIFOs and state in `dir`; sim-1's
/// section changes its exposure.
fn two_cameras(bus: &Bus, dir: &Path) -> Daemon {
    let config = dir.join("sdid.toml");
    std::fs::write(&config, "[camera.\"sim-1\"]\nexposure_us = 1500\n").unwrap();
    let mut cmd = SdidCommand::new()
        .bus(&bus.address)
        .sim()
        .config(&config)
        .state_dir(&dir.join("state"))
        .args(["--cameras", "2", "--sink", "y4m", "--frame-rate-hz", "30"])
        .args(["--y4m-path", &dir.join("view.y4m").display().to_string()])
        .command();
    let d = Daemon::spawn(bus, &mut cmd);
    wait_until("sdid's two cameras", Duration::from_secs(30), || {
        sdictl(&bus.address, &["--camera", "sim-1", "get", "mode"])
            .status
            .success()
    });
    d
}

fn ctl_ok(d: &Daemon, args: &[&str]) -> String {
    sdi_tests::dbus::sdictl_ok(&d.address, args)
}

#[test]
fn two_simulated_cameras_are_two_cameras() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let d = two_cameras(&bus, dir.path());

    // Listed by serial, in order, each on its own object and FIFO.
    let list: serde_json::Value = serde_json::from_str(&ctl_ok(&d, &["--json", "list"])).unwrap();
    let cams = list["cameras"].as_array().unwrap();
    let field = |i: usize, k: &str| cams[i][k].as_str().unwrap().to_owned();
    assert_eq!(cams.len(), 2, "{list}");
    assert_eq!(
        (field(0, "serial"), field(1, "serial")),
        ("sim-0".into(), "sim-1".into())
    );
    assert_eq!(field(0, "path"), "/org/sdi/Camera0");
    assert_eq!(field(1, "path"), "/org/sdi/Camera1");
    for (i, serial) in ["sim-0", "sim-1"].iter().enumerate() {
        let fifo = dir.path().join(format!("view-{serial}.y4m"));
        assert!(
            field(i, "device").ends_with(&fifo.display().to_string()),
            "{list}"
        );
        let mut head = [0u8; 9];
        std::fs::File::open(&fifo)
            .unwrap()
            .read_exact(&mut head)
            .unwrap();
        assert_eq!(&head, b"YUV4MPEG2", "{serial}");
    }

    // Without --camera, sdictl names the choices instead of guessing.
    let out = d.ctl(&["get", "mode"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("sim-0, sim-1") && err.contains("--camera"),
        "{err}"
    );
    let out = d.ctl(&["--camera", "sim-7", "status"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no camera \"sim-7\""));

    // `sdictl doctor`: a line per camera (the host's module checks aside).
    let out = d.ctl(&["--json", "doctor"]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let daemon: Vec<_> = v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["id"] == "daemon")
        .collect();
    assert_eq!(daemon.len(), 2, "{v}");
    for (c, serial) in daemon.iter().zip(["sim-0", "sim-1"]) {
        assert_eq!(c["status"], "ok", "{v}");
        assert!(
            c["summary"]
                .as_str()
                .unwrap()
                .contains(&format!("camera {serial}")),
            "{v}"
        );
    }

    // Each camera's own section and settings.
    let exposure = |s: &str| ctl_ok(&d, &["--camera", s, "get", "exposure-us"]);
    assert_eq!(exposure("sim-1"), "1500.0");
    assert_ne!(exposure("sim-0"), "1500.0");
    ctl_ok(&d, &["--camera", "sim-1", "set-mode", "depth-edge"]);
    let mode = |s: &str| ctl_ok(&d, &["--camera", s, "get", "mode"]);
    assert_eq!(
        (mode("sim-0").as_str(), mode("sim-1").as_str()),
        ("raw", "depth-edge")
    );

    // Snapshots: raw is the sensor's difference (mostly positive where
    // LS1 lights more), depth-edge an edge image (about zero on average).
    let npy = |s: &str| {
        let path = dir.path().join(format!("{s}.npy"));
        ctl_ok(&d, &["--camera", s, "snapshot", path.to_str().unwrap()]);
        let bytes = std::fs::read(&path).unwrap();
        // npy 1.0: magic, version, header length (u16 LE), header.
        let start = 10 + usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
        let (header, data) = bytes.split_at(start);
        let header = String::from_utf8_lossy(header);
        assert!(
            header.contains("'<f4'") && header.contains("(240, 320)"),
            "{s}: {header}"
        );
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect::<Vec<f32>>()
    };
    let (raw, edge) = (npy("sim-0"), npy("sim-1"));
    assert_ne!(raw, edge);
    let mean_abs = |v: &[f32]| v.iter().map(|x| x.abs() as f64).sum::<f64>() / v.len() as f64;
    assert!(mean_abs(&raw) > 0.0 && mean_abs(&edge) > 0.0);
}

/// The mode of the next frame the page's WebSocket carries (a minimal
/// client: the upgrade, then one unmasked binary message from the server).
fn next_page_frame_mode(v: &View) -> String {
    let host = format!("127.0.0.1:{}", v.port);
    let mut s = TcpStream::connect(&host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(
        s,
        "GET /ws?token={} HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n\
         Upgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
        v.token
    )
    .unwrap();
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        s.read_exact(&mut byte).unwrap();
        head.push(byte[0]);
    }
    assert!(
        head.starts_with(b"HTTP/1.1 101"),
        "{}",
        String::from_utf8_lossy(&head)
    );
    let mut b = [0u8; 2];
    s.read_exact(&mut b).unwrap();
    assert_eq!(b[0] & 0x0f, 2, "a binary message");
    let len = match b[1] & 0x7f {
        126 => {
            let mut l = [0u8; 2];
            s.read_exact(&mut l).unwrap();
            u64::from(u16::from_be_bytes(l))
        }
        127 => {
            let mut l = [0u8; 8];
            s.read_exact(&mut l).unwrap();
            u64::from_be_bytes(l)
        }
        n => u64::from(n),
    };
    let mut payload = vec![0u8; len as usize];
    s.read_exact(&mut payload).unwrap();
    let json_len = u32::from_le_bytes([payload[0], payload[1], payload[2], payload[3]]) as usize;
    let meta: serde_json::Value = serde_json::from_slice(&payload[4..4 + json_len]).unwrap();
    meta["mode"].as_str().unwrap().to_owned()
}

#[test]
fn the_viewer_picks_a_camera_and_its_frames_follow() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let d = two_cameras(&bus, dir.path());
    ctl_ok(&d, &["--camera", "sim-1", "set-mode", "depth-edge"]);
    // Without --camera the viewer starts on the first camera.
    let v = View::start(&d, dir.path());
    let get_cameras = || {
        v.response_to(&format!(
            "GET /api/cameras?token={} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nConnection: close\r\n\r\n",
            v.token, v.port
        ))
    };
    let (code, body) = get_cameras();
    assert_eq!(code, 200, "{body}");
    let listed: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(listed["current"], "sim-0", "{listed}");
    assert_eq!(
        listed["cameras"].as_array().map(Vec::len),
        Some(2),
        "{listed}"
    );
    assert_eq!(next_page_frame_mode(&v), "raw");

    // A serial sdid does not serve is refused, and the page stays.
    let (code, body) = v.post("camera", r#"{"serial":"sim-7"}"#);
    assert_eq!(code, 400, "{body}");
    assert!(body.contains("sim-7"), "{body}");

    // The picker moves the page: its status, its controls, its frames.
    let (code, body) = v.post("camera", r#"{"serial":"sim-1"}"#);
    assert_eq!(code, 200, "{body}");
    let (_, status) = v.status();
    let status: serde_json::Value = serde_json::from_str(&status).unwrap();
    assert_eq!(status["properties"]["Serial"], "sim-1", "{status}");
    assert_eq!(next_page_frame_mode(&v), "depth-edge");
    let (code, body) = v.post("set", r#"{"setting":"colormap","value":"grey"}"#);
    assert_eq!(code, 200, "{body}");
    let colormap = |s: &str| ctl_ok(&d, &["--camera", s, "get", "colormap"]);
    assert_eq!(
        (colormap("sim-0").as_str(), colormap("sim-1").as_str()),
        ("diverging", "grey")
    );
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&get_cameras().1).unwrap()["current"],
        "sim-1"
    );
}
