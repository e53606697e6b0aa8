//! Several cameras in one sdid (`--backend sim --cameras 2`): each its own
//! object (listed by the object manager, named by serial), settings,
//! `[camera."SERIAL"]` section and y4m FIFO; `sdictl --camera` reaches
//! one, and without it sdictl refuses to guess.

use std::io::Read;
use std::path::Path;
use std::time::Duration;

use sdi_tests::dbus::{sdictl, Bus, Daemon};
use sdi_tests::process::stdout_of;
use sdi_tests::require_dbus;
use sdi_tests::sdid_command::SdidCommand;
use sdi_tests::wait::wait_until;

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
    let out = d.ctl(args);
    assert!(
        out.status.success(),
        "sdictl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout_of(&out).trim().to_owned()
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
