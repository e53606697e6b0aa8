//! Real hotplug of the board's USB IDs, inside the VM: a configfs USB gadget
//! on dummy_hcd presents 0451:9105 (then 0451:9106, then an ID that is not
//! ours), the real systemd-udevd applies `udev/70-sdi-board.rules` from the
//! VM's throw-away `/etc`, and the test checks what systemd and the control
//! group would see; unplugging the gadget is seen as a remove event.

use std::fs;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use sdi_tests::process::{must as run, repo_root, Reaped};
use sdi_tests::udev::{start_udevd, udevadm, usb_device, wait_initialized, UsbMonitor};
use sdi_tests::wait::wait_until;

const GADGET: &str = "/sys/kernel/config/usb_gadget/sdi-board";
const RULES: &str = "70-sdi-board.rules";
/// How long the kernel and udevd may take to show a change.
const WAIT: Duration = Duration::from_secs(30);

fn write(path: impl AsRef<Path>, value: &str) {
    let path = path.as_ref();
    fs::write(path, value).unwrap_or_else(|e| panic!("write {value:?} to {}: {e}", path.display()));
}

/// Builds the gadget (unbound) with one ACM function.
fn create_gadget() {
    let g = Path::new(GADGET);
    fs::create_dir_all(g).unwrap();
    fs::create_dir_all(g.join("strings/0x409")).unwrap();
    write(g.join("strings/0x409/manufacturer"), "SDI tests");
    write(g.join("strings/0x409/product"), "OPT8241 stand-in");
    write(g.join("strings/0x409/serialnumber"), "SDI0001");
    fs::create_dir_all(g.join("configs/c.1/strings/0x409")).unwrap();
    write(g.join("configs/c.1/strings/0x409/configuration"), "sdi");
    fs::create_dir_all(g.join("functions/acm.usb0")).unwrap();
    std::os::unix::fs::symlink(g.join("functions/acm.usb0"), g.join("configs/c.1/acm.usb0"))
        .unwrap();
}

fn plug(vendor: &str, product: &str) -> PathBuf {
    write(format!("{GADGET}/idVendor"), &format!("0x{vendor}"));
    write(format!("{GADGET}/idProduct"), &format!("0x{product}"));
    write(format!("{GADGET}/UDC"), "dummy_udc.0");
    let mut dev = None;
    wait_until("the gadget to enumerate", WAIT, || {
        dev = usb_device(vendor, product);
        dev.is_some()
    });
    let dev = dev.unwrap();
    wait_initialized(&[&dev]);
    dev
}

/// Unbinds the gadget; returns once udevd has processed the remove event
/// (its database entry for the device is gone).
fn unplug(dev: &Path) {
    let db = db_entry(&properties(dev));
    write(format!("{GADGET}/UDC"), "\n");
    wait_until("the device to disappear", WAIT, || !dev.exists());
    wait_until("udevd to process the remove event", WAIT, || !db.exists());
}

/// udevd's database file of a device, from its MAJOR and MINOR properties.
fn db_entry(props: &str) -> PathBuf {
    let value = |key: &str| {
        props
            .lines()
            .find_map(|l| l.strip_prefix(key))
            .unwrap_or_else(|| panic!("no {key} in\n{props}"))
            .to_owned()
    };
    let db = PathBuf::from(format!(
        "/run/udev/data/c{}:{}",
        value("MAJOR="),
        value("MINOR=")
    ));
    assert!(
        db.exists(),
        "{} missing for an initialized device",
        db.display()
    );
    db
}

/// `udevadm info` properties as KEY=VALUE lines.
fn properties(dev: &Path) -> String {
    let out = run(udevadm().args(["info", "--query=property"]).arg(dev));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn device_node(props: &str) -> PathBuf {
    props
        .lines()
        .find_map(|l| l.strip_prefix("DEVNAME="))
        .map(PathBuf::from)
        .expect("USB device without DEVNAME")
}

fn gid_of(group: &str) -> u32 {
    let out = run(Command::new("getent").args(["group", group]));
    String::from_utf8_lossy(&out.stdout)
        .split(':')
        .nth(2)
        .and_then(|g| g.trim().parse().ok())
        .expect("gid")
}

fn setup() -> Reaped {
    run(Command::new("groupadd").args(["--system", "sdi"]));
    fs::create_dir_all("/etc/udev/rules.d").unwrap();
    fs::copy(
        repo_root().join("udev").join(RULES),
        Path::new("/etc/udev/rules.d").join(RULES),
    )
    .unwrap();
    for module in ["dummy_hcd", "libcomposite", "usb_f_acm"] {
        run(Command::new("modprobe").arg(module));
    }
    if !Path::new("/sys/kernel/config/usb_gadget").exists() {
        run(Command::new("mount").args(["-t", "configfs", "none", "/sys/kernel/config"]));
    }
    start_udevd()
}

#[test]
fn board_hotplug_tags_device_for_systemd_and_group() {
    if crate::GUEST.on_host() {
        return;
    }
    let _udevd = setup();
    let sdi_gid = gid_of("sdi");
    create_gadget();

    // Our rules parse cleanly: udevadm test loads every rules file and
    // complains about the ones it cannot read.
    let dev = plug("0451", "9105");
    let test = run(udevadm().args(["test", "--action=add"]).arg(&dev));
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&test.stdout),
        String::from_utf8_lossy(&test.stderr)
    );
    let complaints: Vec<&str> = log
        .lines()
        .filter(|l| l.contains(RULES))
        .filter(|l| {
            let l = l.to_lowercase();
            l.contains("invalid") || l.contains("error") || l.contains("ignoring")
        })
        .collect();
    assert!(
        complaints.is_empty(),
        "udev complains about {RULES}: {complaints:#?}"
    );
    assert!(
        log.contains("SYSTEMD_WANTS=sdid.service"),
        "udevadm test:\n{log}"
    );
    unplug(&dev);

    for (product, mode) in [
        ("9105", Some("bulk")),
        ("9106", Some("uvc")),
        ("9107", None),
    ] {
        let mut monitor = UsbMonitor::start();

        let dev = plug("0451", product);
        let props = properties(&dev);
        let node = device_node(&props);
        let meta = fs::metadata(&node).unwrap();
        eprintln!("0451:{product} at {}:\n{props}", dev.display());
        match mode {
            Some(mode) => {
                assert!(
                    props.contains("TAGS=") && props.contains(":systemd:"),
                    "{props}"
                );
                assert!(
                    props.lines().any(|l| l == "SYSTEMD_WANTS=sdid.service"),
                    "{props}"
                );
                assert!(props
                    .lines()
                    .any(|l| l == format!("ID_SDI_BOARD_MODE={mode}")));
                assert_eq!(
                    meta.gid(),
                    sdi_gid,
                    "{} not owned by group sdi",
                    node.display()
                );
                assert_eq!(meta.permissions().mode() & 0o777, 0o660);
            }
            None => {
                assert!(
                    !props.contains("SYSTEMD_WANTS"),
                    "foreign device matched:\n{props}"
                );
                assert!(!props.contains("ID_SDI_BOARD"), "{props}");
                assert_ne!(meta.gid(), sdi_gid);
            }
        }

        unplug(&dev);
        assert!(
            !node.exists(),
            "{} still exists after unplug",
            node.display()
        );
        let devpath = dev
            .strip_prefix("/sys")
            .unwrap()
            .to_string_lossy()
            .into_owned();
        // udevd broadcasts the event right after updating its database.
        wait_until("udevadm monitor to print the remove event", WAIT, || {
            monitor
                .output()
                .lines()
                .any(|l| l.contains("remove") && l.contains(&devpath))
        });
        let out = monitor.stop();
        assert!(
            out.lines()
                .any(|l| l.contains("add") && l.contains(&devpath)),
            "no add event for {devpath}:\n{out}"
        );
        assert!(
            out.lines()
                .any(|l| l.contains("remove") && l.contains(&devpath)),
            "no remove event for {devpath}:\n{out}"
        );
    }
}
