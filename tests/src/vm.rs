//! Running a test inside the QEMU VM of `tests/vm/vmrun`.
//!
//! Pattern: a host-side test re-executes its own test binary inside the VM
//! (`IN_VM=1`), where the real kernel modules (v4l2loopback, dummy_hcd, ...)
//! can be loaded; inside, the same test does the real work. VMs are
//! serialized with a lock file so parallel test binaries do not starve each
//! other on a 2-core machine.

use std::path::PathBuf;
use std::process::Command;

/// True inside the VM.
pub fn in_vm() -> bool {
    std::env::var_os("IN_VM").is_some()
}

/// Path of the launcher script.
pub fn vmrun_path() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/vm/vmrun"))
}

/// Why the VM cannot run here, if it cannot.
pub fn unavailable_reason() -> Option<String> {
    let qemu = Command::new("qemu-system-x86_64").arg("--version").output();
    if !matches!(qemu, Ok(ref o) if o.status.success()) {
        return Some(
            "qemu-system-x86_64 is not installed (run: sudo tests/vm/setup-host.sh)".into(),
        );
    }
    let kernels = std::fs::read_dir("/boot").ok()?;
    let has_module = kernels.flatten().any(|e| {
        let name = e.file_name().to_string_lossy().into_owned();
        name.strip_prefix("vmlinuz-").is_some_and(|kver| {
            std::path::Path::new(&format!("/lib/modules/{kver}/updates/dkms")).exists()
        })
    });
    (!has_module).then(|| {
        "no Debian kernel with v4l2loopback built by DKMS (run: sudo tests/vm/setup-host.sh)".into()
    })
}

/// Runs test `name` of the current test binary inside the VM and asserts it
/// passed there. Returns false (after printing why) when no VM can run here;
/// with `SDI_REQUIRE_VM=1` (set by CI) that is a failure instead.
pub fn run_test_in_vm(name: &str, timeout_s: u32) -> bool {
    if let Some(reason) = unavailable_reason() {
        assert!(
            std::env::var_os("SDI_REQUIRE_VM").is_none(),
            "VM test {name} cannot run and SDI_REQUIRE_VM is set: {reason}"
        );
        crate::skipped!("SKIPPED (no VM): {name}: {reason}");
        return false;
    }
    let exe = std::env::current_exe().expect("test binary path");
    // Wait at most 30 min for other VM tests; vmrun itself enforces
    // `timeout_s` (exit 124) and kills QEMU on any exit path.
    let status = Command::new("flock")
        .args(["-w", "1800", "-E", "75"])
        .arg(std::env::temp_dir().join("sdi-vm.lock"))
        .arg(vmrun_path())
        .args([
            "-s",
            "2",
            "-t",
            &timeout_s.to_string(),
            "-e",
            "IN_VM=1",
            "--",
        ])
        .arg(&exe)
        .args(["--exact", name, "--nocapture", "--test-threads=1"])
        .status()
        .expect("spawn vmrun");
    assert!(
        status.success(),
        "{name} failed inside the VM ({status}; 124 = timeout after {timeout_s} s, \
         125 = VM died (console tail above), 75 = waited 30 min for the VM lock)"
    );
    true
}

/// The host side of a VM test that drives sdid and sdictl: names the
/// programs for the guest ([`crate::dbus::export_bins`]), runs test `name`
/// of this binary inside the VM (at most `timeout_s`) and returns true;
/// inside the VM returns false, so the test goes on to do the work.
pub fn rerun_with_bins(name: &str, timeout_s: u32) -> bool {
    if in_vm() {
        return false;
    }
    crate::dbus::export_bins();
    run_test_in_vm(name, timeout_s);
    true
}
