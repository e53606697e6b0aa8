//! Several cameras on v4l2loopback: `sdid --backend sim --cameras 2 --sink
//! loopback` publishes each camera on the node labelled with its serial
//! ("SDI camera sim-0", "SDI camera sim-1"); both stream, and a mode set
//! on one camera leaves the other.

use std::path::Path;
use std::time::Duration;

use sdi_tests::capture::read_frames;
use sdi_tests::dbus::{sdictl, Bus, Daemon};
use sdi_tests::loopback::{modprobe, unload_module};
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
