//! `udev/modprobe.d/sdi-v4l2loopback.conf` with the real module, inside the
//! VM: a plain `modprobe v4l2loopback` (what modules-load.d and
//! modprobe@v4l2loopback.service run) creates the camera at the fixed node,
//! with SDI's card label and exclusive_caps on.

use std::fs;
use std::path::Path;
use std::process::Command;

#[test]
fn plain_modprobe_creates_the_sdi_camera() {
    if crate::GUEST.on_host() {
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    fs::create_dir_all("/etc/modprobe.d").unwrap();
    fs::copy(
        root.join("udev/modprobe.d/sdi-v4l2loopback.conf"),
        "/etc/modprobe.d/sdi-v4l2loopback.conf",
    )
    .unwrap();
    let module =
        fs::read_to_string(root.join("udev/modules-load.d/sdi-v4l2loopback.conf")).unwrap();
    let name = module
        .lines()
        .find(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
        .expect("modules-load.d names a module")
        .trim();
    assert_eq!(name, "v4l2loopback");
    let ok = Command::new("modprobe").arg(name).status().unwrap();
    assert!(ok.success(), "modprobe {name} failed");

    assert!(Path::new("/dev/video42").exists(), "no /dev/video42");
    let label = fs::read_to_string("/sys/devices/virtual/video4linux/video42/name").unwrap();
    assert_eq!(label.trim(), "SDI camera");
    // exclusive_caps=1: with no writer yet, the node is an output device
    // only (it turns into a capture-only device once sdid writes).
    let info = Command::new("v4l2-ctl")
        .args(["-d", "/dev/video42", "--info"])
        .output()
        .unwrap();
    let info = String::from_utf8_lossy(&info.stdout);
    eprintln!("{info}");
    let device_caps = info
        .split("Device Caps")
        .nth(1)
        .expect("v4l2-ctl --info shows Device Caps");
    assert!(device_caps.contains("Video Output"), "{info}");
    assert!(
        !device_caps.contains("Video Capture"),
        "exclusive_caps is off:\n{info}"
    );
}
