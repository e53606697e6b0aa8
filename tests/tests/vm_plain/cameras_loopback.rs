//! Several cameras on v4l2loopback: `sdid --backend sim --cameras 2 --sink
//! loopback` publishes each camera on the node labelled with its serial
//! ("SDI camera sim-0", "SDI camera sim-1"); both stream, and a mode set
//! on one camera leaves the other. Where the module has no such nodes,
//! sdid adds them through /dev/v4l2loopback (0.15), once; on 0.12.7 it
//! cannot, and says why.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use sdi_tests::capture::read_frames;
use sdi_tests::dbus::{sdictl, Bus, Daemon};
use sdi_tests::loopback::{load_module, modprobe, unload_module, ModuleBuild, ModuleParams};
use sdi_tests::process::Reaped;
use sdi_tests::wait::wait_until;

fn ctl(bus: &Bus, args: &[&str]) -> String {
    sdi_tests::dbus::sdictl_ok(&bus.address, args)
}

/// Two YUYV frames of `dev`, read by ffmpeg.
fn two_frames(dev: &str, tmp: &Path) -> Vec<u8> {
    read_frames(Path::new(dev), 2, "yuyv422", &tmp.join("frames.raw"))
        .unwrap_or_else(|e| panic!("{dev}: {e}"))
}

#[test]
fn vm_two_cameras_on_their_own_labelled_nodes() {
    if crate::GUEST.on_host() {
        return;
    }
    modprobe(&[(60, "SDI camera sim-0"), (61, "SDI camera sim-1")]);
    let tmp = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    let _sdid = Reaped(
        Daemon::bare_command(&bus, &[])
            .args(["--backend", "sim", "--cameras", "2", "--sink", "loopback"])
            .args(["--frame-rate-hz", "30"])
            .spawn()
            .expect("start sdid"),
    );
    wait_until("sdid's two cameras", Duration::from_secs(60), || {
        sdictl(&bus.address, &["--camera", "sim-1", "get", "mode"])
            .status
            .success()
    });
    for (serial, dev) in [("sim-0", "/dev/video60"), ("sim-1", "/dev/video61")] {
        let device = ctl(&bus, &["--camera", serial, "get", "device"]);
        assert!(device.contains(dev), "{serial}: {device}");
    }
    // Both nodes stream, each its camera's frames.
    for dev in ["/dev/video60", "/dev/video61"] {
        assert_eq!(
            two_frames(dev, tmp.path()).len(),
            2 * 640 * 480 * 2,
            "{dev}"
        );
    }
    ctl(&bus, &["--camera", "sim-1", "set-mode", "depth-edge"]);
    assert_eq!(ctl(&bus, &["--camera", "sim-0", "get", "mode"]), "raw");
    assert_eq!(
        two_frames("/dev/video61", tmp.path()).len(),
        2 * 640 * 480 * 2
    );
    drop(_sdid);
    let _ = unload_module();
}

/// The loopback nodes as (path, label), from sysfs.
fn nodes() -> Vec<(PathBuf, String)> {
    let mut nodes: Vec<_> = std::fs::read_dir("/sys/devices/virtual/video4linux")
        .map(|d| d.flatten().collect::<Vec<_>>())
        .unwrap_or_default()
        .into_iter()
        .filter_map(|e| {
            let name = std::fs::read_to_string(e.path().join("name")).ok()?;
            Some((
                Path::new("/dev").join(e.file_name()),
                name.trim_end().into(),
            ))
        })
        .collect();
    nodes.sort();
    nodes
}

const ADDED: &str = "added v4l2loopback node";

/// sdid with two simulated cameras, each with a view and a data node, on
/// the loopback sink, logging at info level to `log`.
fn two_cameras(bus: &Bus, tmp: &Path, log: &str) -> Reaped {
    let config = tmp.join("sdid.toml");
    std::fs::write(&config, "[output]\ndata_label = \"SDI data\"\n").unwrap();
    let sdid = Reaped(
        Daemon::bare_command(bus, &[])
            .env("RUST_LOG", "info")
            .arg("--config")
            .arg(&config)
            .args(["--backend", "sim", "--cameras", "2", "--sink", "loopback"])
            .args(["--frame-rate-hz", "30"])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(tmp.join(log)).unwrap())
            .spawn()
            .expect("start sdid"),
    );
    wait_until("sdid's two cameras", Duration::from_secs(60), || {
        ["sim-0", "sim-1"].iter().all(|serial| {
            sdictl(&bus.address, &["--camera", serial, "get", "mode"])
                .status
                .success()
        })
    });
    sdid
}

#[test]
fn vm_sdid_adds_each_cameras_nodes_once() {
    if crate::GUEST.on_host() {
        return;
    }
    // 0.15 with no node at all (devices=0): sdid adds all four.
    load_module(ModuleBuild::V0150, &ModuleParams::default()).expect("insmod 0.15.0");
    assert!(nodes().is_empty(), "devices=0: {:?}", nodes());
    let tmp = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    let labels = [
        "SDI camera sim-0",
        "SDI camera sim-1",
        "SDI data sim-0",
        "SDI data sim-1",
    ];
    let sdid = two_cameras(&bus, tmp.path(), "first.log");
    let first = nodes();
    let mut found: Vec<&str> = first.iter().map(|(_, l)| l.as_str()).collect();
    found.sort();
    assert_eq!(found, labels, "{first:?}");
    let log = std::fs::read_to_string(tmp.path().join("first.log")).unwrap();
    assert_eq!(log.matches(ADDED).count(), 4, "{log}");
    for serial in ["sim-0", "sim-1"] {
        let label = format!("SDI camera {serial}");
        let (view, _) = first.iter().find(|(_, l)| *l == label).unwrap();
        let view = view.display().to_string();
        let device = ctl(&bus, &["--camera", serial, "get", "device"]);
        // "simulator (...), camera sim-0 -> /dev/videoV + /dev/videoD (Y16 data)"
        assert!(
            device.contains(&format!("-> {view} ")),
            "{serial}: {device}"
        );
        assert_eq!(
            two_frames(&view, tmp.path()).len(),
            2 * 640 * 480 * 2,
            "{view}"
        );
    }
    // A restart finds them by label: no second set.
    drop(sdid);
    let sdid = two_cameras(&bus, tmp.path(), "second.log");
    assert_eq!(nodes(), first, "after the restart");
    let log = std::fs::read_to_string(tmp.path().join("second.log")).unwrap();
    assert_eq!(log.matches(ADDED).count(), 0, "{log}");
    let (view, _) = first.iter().find(|(_, l)| l == "SDI camera sim-1").unwrap();
    assert_eq!(
        two_frames(&view.display().to_string(), tmp.path()).len(),
        2 * 640 * 480 * 2
    );
    drop(sdid);

    // 0.12.7 has no control device: sdid stops as before, saying why.
    modprobe(&[(62, "not SDI")]);
    let out = Daemon::bare_command(&bus, &["timeout", "60"])
        .args(["--backend", "sim", "--sink", "loopback"])
        .output()
        .expect("run sdid");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("no v4l2loopback device labelled \"SDI camera\"")
            && err.contains("not added: this v4l2loopback has no control device"),
        "{err}"
    );
    assert_eq!(nodes().len(), 1, "nothing added on 0.12.7");
    let _ = unload_module();
}
