//! The VM tests that run browsers on the loopback camera or install the
//! Debian packages: one guest with [`vm::DESKTOP_MEM_MB`] of RAM (Chromium
//! and Firefox need more than the harness's default), booted once for this
//! test binary; each test in
//! a sandbox of its own (`tests/vm/guest-run`). Map and budget:
//! tests/README.md.

mod browsers;
mod package;

use sdi_tests::vm::{self, Guest};

/// Every test of this binary, with its own time limit in seconds, in the
/// order the guest runs them.
static GUEST: Guest = Guest::new(&[
    ("browsers::vm_browsers_see_the_sdi_camera", 1500),
    (
        "package::vm_apt_installs_activates_and_purges_the_package",
        1200,
    ),
])
.with_mem_mb(vm::DESKTOP_MEM_MB)
.prepared_by(prepare);

/// The programs the host built, and the Debian packages (`SDI_DEB`,
/// `SDI_CAMERA_DEB`) when they can be built here; without them the
/// package test skips in the guest.
fn prepare() -> bool {
    sdi_tests::dbus::export_bins();
    let _ = sdi_tests::package::export_for_vm(
        "the camera package's part of package::vm_apt_installs_activates_and_purges_the_package",
    );
    true
}
