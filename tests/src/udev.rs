//! systemd-udevd in the VM, and waiting for it without `udevadm settle`.
//!
//! `udevadm settle` first pings udevd over `/run/udev/control`, and udevd 252
//! (Debian 12) turns on SO_PASSCRED only after accepting the connection: a
//! ping that arrives before that carries no credentials, udevd logs "Invalid
//! sender uid 65534, ignoring message", closes the socket, and settle fails
//! with "Broken pipe" (seen once in a fresh CI run, in vm_plain/hotplug). The
//! waits here never use the control socket: `udevadm wait` watches the udev
//! database with inotify, and `udevadm trigger --settle` listens for the
//! events it caused on the udev monitor.

use std::collections::HashMap;
use std::fs;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::process::{must, Reaped};
use crate::wait::wait_until;

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

/// `udevadm monitor --udev --property` for USB devices, its output
/// collected as it comes.
pub struct UsbMonitor {
    child: Reaped,
    out: Arc<Mutex<String>>,
    reader: Option<std::thread::JoinHandle<()>>,
}

impl UsbMonitor {
    /// Starts the monitor and returns once it is subscribed: it has printed
    /// a synthetic change event of the root hub (a fixed wait was not
    /// always enough under TCG, and the add event went unseen).
    pub fn start() -> Self {
        let mut child = udevadm()
            .args([
                "monitor",
                "--udev",
                "--property",
                "--subsystem-match=usb/usb_device",
            ])
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn udevadm monitor");
        let stdout = child.stdout.take().expect("monitor stdout");
        let out = Arc::new(Mutex::new(String::new()));
        let sink = out.clone();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let mut s = sink.lock().expect("monitor output");
                s.push_str(&line);
                s.push('\n');
            }
        });
        let m = Self {
            child: Reaped(child),
            out,
            reader: Some(reader),
        };
        let mut last_trigger: Option<Instant> = None;
        wait_until(
            "udevadm monitor to subscribe",
            Duration::from_secs(30),
            || {
                if last_trigger.is_none_or(|t| t.elapsed() > Duration::from_secs(1)) {
                    let _ = udevadm()
                        .args(["trigger", "--action=change", "/sys/bus/usb/devices/usb1"])
                        .status();
                    last_trigger = Some(Instant::now());
                }
                m.output().lines().any(|l| l.contains(" change "))
            },
        );
        m
    }

    /// Everything printed so far.
    pub fn output(&self) -> String {
        self.out.lock().expect("monitor output").clone()
    }

    /// The events so far, each as its properties (`ACTION`, `DEVPATH`,
    /// `SYSTEMD_WANTS`, ...).
    pub fn events(&self) -> Vec<HashMap<String, String>> {
        let out = self.output();
        // The last block is complete once a blank line follows it.
        let complete = out.rsplit_once("\n\n").map_or("", |(c, _)| c);
        complete
            .split("\n\n")
            .map(|block| {
                block
                    .lines()
                    .filter_map(|l| l.split_once('='))
                    .map(|(k, v)| (k.to_owned(), v.to_owned()))
                    .collect::<HashMap<_, _>>()
            })
            .filter(|e| e.contains_key("ACTION"))
            .collect()
    }

    /// Ends the monitor; everything it printed.
    pub fn stop(&mut self) -> String {
        let _ = self.child.0.kill();
        let _ = self.child.0.wait();
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        self.output()
    }
}
