//! The VM harness itself: boots, loads the modules the other tests need.

use std::process::Command;

use sdi_tests::vm;

#[test]
fn vm_boots_and_loads_modules() {
    if !vm::in_vm() {
        vm::run_test_in_vm("vm_boots_and_loads_modules", 180);
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
