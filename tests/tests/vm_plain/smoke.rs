//! The VM harness itself: boots, loads the modules the other tests need.

use std::process::Command;

#[test]
fn vm_boots_and_loads_modules() {
    if crate::GUEST.on_host() {
        return;
    }
    for module in ["v4l2loopback", "dummy_hcd", "libcomposite", "usb_f_fs"] {
        let ok = Command::new("modprobe")
            .arg(module)
            .status()
            .expect("modprobe");
        assert!(ok.success(), "modprobe {module} failed");
    }
}
