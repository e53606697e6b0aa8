//! `sdictl doctor` on the host (no v4l2loopback: the module check fails
//! with the install fix, exit status 1; a fake sysfs tree shows the node,
//! board and Secure Boot checks) and in the VM with the module present and
//! each fault injected: exclusive_caps=0, max_buffers=2, the daemon down,
//! the caller outside groups sdi/video, Secure Boot on with an unsigned
//! module; and everything fixed gives exit status 0.

use std::path::Path;
use std::process::Command;

use serde_json::Value;

use sdi_tests::clients::{self, Sdid, PMD};
use sdi_tests::loopback::{self, ModuleBuild, ModuleParams};
use sdi_tests::vm;

/// Runs `sdictl doctor --json ARGS` (as `user` when given); (exit code, report).
fn doctor(sdictl: &Path, args: &[&str], user: Option<&str>) -> (i32, Value) {
    let mut cmd = match user {
        Some(u) => {
            let mut c = Command::new("runuser");
            c.args(["-u", u, "--"]).arg(sdictl);
            c
        }
        None => Command::new(sdictl),
    };
    let out = cmd
        .args(["doctor", "--json"])
        .args(args)
        .output()
        .expect("run sdictl doctor");
    let text = String::from_utf8_lossy(&out.stdout);
    let v: Value = serde_json::from_str(&text).unwrap_or_else(|e| {
        panic!(
            "doctor --json is not JSON ({e}): {text}\n{}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    eprintln!("doctor {args:?} as {user:?} -> {:?}", out.status.code());
    for c in v["checks"].as_array().into_iter().flatten() {
        eprintln!("  [{}] {}: {}", c["status"], c["id"], c["summary"]);
    }
    (out.status.code().unwrap_or(-1), v)
}

/// The check `id` of a report.
fn check<'a>(v: &'a Value, id: &str) -> &'a Value {
    v["checks"]
        .as_array()
        .and_then(|a| a.iter().find(|c| c["id"] == id))
        .unwrap_or_else(|| panic!("no check {id} in {v}"))
}

fn status(v: &Value, id: &str) -> String {
    check(v, id)["status"].as_str().unwrap_or("").to_owned()
}

fn fix(v: &Value, id: &str) -> String {
    check(v, id)["fix"].as_str().unwrap_or("").to_owned()
}

fn write(root: &Path, path: &str, text: &str) {
    let p = root.join(path);
    std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
    std::fs::write(p, text).expect("write");
}

/// A fake sysfs: v4l2loopback loaded with the view node at 42 (`caps`,
/// `buffers`), a board in UVC mode at full speed, Secure Boot on.
fn fake_sysroot(root: &Path, caps: &str, buffers: &str) {
    let m = "sys/module/v4l2loopback";
    write(root, &format!("{m}/version"), "0.15.0\n");
    write(root, &format!("{m}/taint"), "OE\n");
    write(root, &format!("{m}/parameters/video_nr"), "42,-1\n");
    write(
        root,
        &format!("{m}/parameters/exclusive_caps"),
        &format!("{caps},N\n"),
    );
    write(
        root,
        &format!("{m}/parameters/max_buffers"),
        &format!("{buffers}\n"),
    );
    write(root, "sys/class/video4linux/video42/name", "SDI camera\n");
    let driver = root.join("sys/bus/platform/drivers/v4l2loopback");
    std::fs::create_dir_all(&driver).expect("mkdir driver");
    let dev = root.join("sys/class/video4linux/video42/device");
    std::fs::create_dir_all(&dev).expect("mkdir device");
    let _ = std::fs::remove_file(dev.join("driver"));
    std::os::unix::fs::symlink(&driver, dev.join("driver")).expect("symlink driver");
    let usb = "sys/bus/usb/devices/1-1";
    write(root, &format!("{usb}/idVendor"), "0451\n");
    write(root, &format!("{usb}/idProduct"), "9106\n");
    write(root, &format!("{usb}/speed"), "12\n");
    secure_boot_on(root);
    write(
        root,
        "sys/kernel/security/lockdown",
        "none [integrity] confidentiality\n",
    );
}

/// A fake efivars tree below `root` that says Secure Boot is on.
fn secure_boot_on(root: &Path) {
    let efi = root.join("sys/firmware/efi/efivars");
    std::fs::create_dir_all(&efi).expect("mkdir efivars");
    std::fs::write(
        efi.join("SecureBoot-8be4df61-93ca-11d2-aa0d-e98c6b8a5a42"),
        [6, 0, 0, 0, 1],
    )
    .expect("SecureBoot");
}

#[test]
fn doctor_on_the_host_without_the_module() {
    if vm::in_vm() {
        return;
    }
    let sdictl = sdi_tests::dbus::bin("sdictl");
    let no_bus = ["--bus-address", "unix:path=/nonexistent/sdi-doctor"];
    let (code, v) = doctor(&sdictl, &no_bus, None);
    assert_eq!(code, 1, "a missing module and daemon block: {v}");
    assert_eq!(v["ok"], false);
    if !Path::new("/sys/module/v4l2loopback").exists() {
        assert_eq!(status(&v, "module"), "fail");
        assert!(fix(&v, "module").contains("modprobe v4l2loopback"), "{v}");
        assert_eq!(status(&v, "nodes"), "skip");
    }
    assert_eq!(status(&v, "daemon"), "fail");
    assert!(fix(&v, "daemon").contains("systemctl"), "{v}");

    // The same checks over a fake sysfs: nodes, board, Secure Boot.
    let tmp = tempfile::tempdir().expect("tempdir");
    let root = tmp.path();
    fake_sysroot(root, "Y", "10");
    let sysroot = root.display().to_string();
    let args = ["--sysroot", &sysroot, no_bus[0], no_bus[1]];
    let (_, v) = doctor(&sdictl, &args, None);
    assert_eq!(status(&v, "module"), "ok", "{v}");
    assert!(check(&v, "module")["summary"]
        .as_str()
        .is_some_and(|s| s.contains("0.15.0")));
    assert_eq!(status(&v, "view-node"), "ok", "{v}");
    assert_eq!(status(&v, "secure-boot"), "ok", "loaded: it got in: {v}");
    assert!(check(&v, "secure-boot")["summary"]
        .as_str()
        .is_some_and(|s| s.contains("Secure Boot on") && s.contains("unsigned")));
    assert_eq!(status(&v, "board"), "warn", "full speed: {v}");
    assert!(check(&v, "board")["summary"]
        .as_str()
        .is_some_and(|s| s.contains("uvc mode")));
    fake_sysroot(root, "N", "2");
    let (_, v) = doctor(&sdictl, &args, None);
    let view: Vec<&Value> = v["checks"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|c| c["id"] == "view-node")
        .collect();
    assert_eq!(view.len(), 2, "{v}");
    assert!(view.iter().all(|c| c["status"] == "fail"), "{v}");
    assert!(view.iter().any(|c| c["summary"]
        .as_str()
        .is_some_and(|s| s.contains("exclusive_caps=0"))));
    assert!(view.iter().any(|c| c["summary"]
        .as_str()
        .is_some_and(|s| s.contains("max_buffers=2"))));
}

fn in_vm_checks() {
    // Run as other users too: a copy they can reach.
    let sdictl = sdi_tests::process::runnable_copy(
        &sdi_tests::dbus::bin("sdictl"),
        Path::new("/tmp/sdi-doctor-bin"),
    );
    // Module present, nodes as udev/modprobe.d sets them, sdid streaming.
    clients::load_module(40, 41);
    let sdid = Sdid::start(40, 41, PMD, 15);
    let bus = ["--bus-address", sdid.bus.address.as_str()];
    let (code, v) = doctor(&sdictl, &bus, None);
    assert_eq!(status(&v, "module"), "ok", "{v}");
    assert_eq!(status(&v, "view-node"), "ok", "{v}");
    assert_eq!(status(&v, "daemon"), "ok", "{v}");
    assert!(check(&v, "daemon")["summary"]
        .as_str()
        .is_some_and(|s| s.contains("the bus at")));
    assert_eq!(status(&v, "group-sdi"), "ok", "root: {v}");
    assert_eq!(code, 0, "nothing blocks: {v}");
    assert_eq!(v["ok"], true);

    // The daemon down.
    drop(sdid);
    let gone = ["--bus-address", "unix:path=/run/sdi-doctor-no-such-bus"];
    let (code, v) = doctor(&sdictl, &gone, None);
    assert_eq!((code, status(&v, "daemon").as_str()), (1, "fail"), "{v}");

    // exclusive_caps=0 and max_buffers=2.
    let mut p = ModuleParams::nodes(&[(40, "SDI camera")]);
    p.exclusive_caps = false;
    p.extra.push("max_buffers=2".into());
    loopback::load_module(ModuleBuild::Debian0127, &p).expect("reload v4l2loopback");
    let (code, v) = doctor(&sdictl, &gone, None);
    assert_eq!(code, 1);
    let fails: Vec<String> = v["checks"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|c| c["id"] == "view-node" && c["status"] == "fail")
        .filter_map(|c| c["summary"].as_str().map(str::to_owned))
        .collect();
    assert!(fails.iter().any(|s| s.contains("exclusive_caps=0")), "{v}");
    assert!(fails.iter().any(|s| s.contains("max_buffers=2")), "{v}");
    assert!(
        fix(&v, "view-node").contains("modprobe -r v4l2loopback"),
        "{v}"
    );

    // Module not loaded: installed, the load command is the fix.
    loopback::unload_module().expect("rmmod");
    let (_, v) = doctor(&sdictl, &gone, None);
    assert_eq!(status(&v, "module"), "fail", "{v}");
    assert!(check(&v, "module")["summary"]
        .as_str()
        .is_some_and(|s| s.contains("installed but not loaded")));

    // Secure Boot on (a fake efivars tree), module installed, not loaded:
    // unsigned -> the "Key was rejected by service" case with MOK steps.
    let root = Path::new("/tmp/sdi-doctor-root");
    secure_boot_on(root);
    let (_, v) = doctor(
        &sdictl,
        &["--sysroot", "/tmp/sdi-doctor-root", gone[0], gone[1]],
        None,
    );
    let signer = Command::new("modinfo")
        .args(["-F", "signer", "v4l2loopback"])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .unwrap_or_default();
    let expected = if signer.is_empty() { "fail" } else { "warn" };
    assert_eq!(
        status(&v, "secure-boot"),
        expected,
        "signer {signer:?}: {v}"
    );
    assert!(fix(&v, "secure-boot").contains("mokutil --import"), "{v}");

    // A user outside groups sdi and video, then in them (a new login).
    for cmd in [
        vec!["groupadd", "--system", "sdi"],
        vec!["useradd", "--create-home", "ann"],
    ] {
        let s = Command::new(cmd[0])
            .args(&cmd[1..])
            .status()
            .expect("spawn");
        assert!(s.success(), "{cmd:?}");
    }
    let (_, v) = doctor(&sdictl, &gone, Some("ann"));
    assert_eq!(status(&v, "group-sdi"), "fail", "{v}");
    assert!(fix(&v, "group-sdi").contains("usermod -aG sdi ann"), "{v}");
    assert_eq!(status(&v, "group-video"), "fail", "{v}");
    let s = Command::new("usermod")
        .args(["-aG", "sdi,video", "ann"])
        .status()
        .expect("usermod");
    assert!(s.success());
    let (_, v) = doctor(&sdictl, &gone, Some("ann"));
    assert_eq!(status(&v, "group-sdi"), "ok", "{v}");
    assert_eq!(status(&v, "group-video"), "ok", "{v}");
}

#[test]
fn vm_doctor_with_the_module_and_faults() {
    if crate::GUEST.on_host() {
        return;
    }
    in_vm_checks();
}
