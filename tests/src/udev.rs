//! systemd-udevd in the VM, and waiting for it without `udevadm settle`.
//!
//! `udevadm settle` first pings udevd over `/run/udev/control`, and udevd 252
//! (Debian 12) turns on SO_PASSCRED only after accepting the connection: a
//! ping that arrives before that carries no credentials, udevd logs "Invalid
//! sender uid 65534, ignoring message", closes the socket, and settle fails
//! with "Broken pipe" (seen once in a fresh CI run, in system_hotplug). The
//! waits here never use the control socket: `udevadm wait` watches the udev
//! database with inotify, and `udevadm trigger --settle` listens for the
//! events it caused on the udev monitor.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::process::{must, Reaped};

/// `udevadm`; the VM runs tests in a chroot, where udevadm would otherwise
/// refuse to settle, wait or monitor.
pub fn udevadm() -> Command {
    let mut cmd = Command::new("udevadm");
    cmd.env("SYSTEMD_IGNORE_CHROOT", "1");
    cmd
}

/// Starts systemd-udevd in the foreground (killed on drop) and returns once
/// its control socket exists.
pub fn start_udevd() -> Reaped {
    let child = Command::new("/lib/systemd/systemd-udevd")
        .env("SYSTEMD_IGNORE_CHROOT", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn systemd-udevd");
    let udevd = Reaped(child);
    let deadline = Instant::now() + Duration::from_secs(30);
    while !Path::new("/run/udev/control").exists() {
        assert!(Instant::now() < deadline, "systemd-udevd did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    udevd
}

/// Waits until udevd has processed the add events of `devices` (sysfs paths
/// or device nodes) and its queue is empty.
pub fn wait_initialized(devices: &[&Path]) {
    must(
        udevadm()
            .args(["wait", "--settle", "--timeout=30"])
            .args(devices),
    );
}

/// Runs `udevadm trigger ARGS --settle`: returns once udevd has processed
/// every event the trigger caused.
pub fn trigger_settled(args: &[&str]) {
    must(udevadm().arg("trigger").args(args).arg("--settle"));
}

/// The enumerated USB device (sysfs path, canonical) with this
/// vendor:product, e.g. the host side of a gadget.
pub fn usb_device(vendor: &str, product: &str) -> Option<PathBuf> {
    fs::read_dir("/sys/bus/usb/devices")
        .ok()?
        .flatten()
        .find_map(|e| {
            let p = e.path();
            let attr = |name: &str| fs::read_to_string(p.join(name)).map(|s| s.trim().to_owned());
            (attr("idVendor").ok()? == vendor && attr("idProduct").ok()? == product)
                .then(|| fs::canonicalize(&p).unwrap_or(p))
        })
}
