//! Running a test inside the QEMU VM of `tests/vm/vmrun`.
//!
//! Pattern: a host-side test re-executes its own test binary inside the VM
//! (`IN_VM=1`), where the real kernel modules (v4l2loopback, dummy_hcd, ...)
//! can be loaded; inside, the same test does the real work. VMs are
//! serialized with a lock file so parallel test binaries do not starve each
//! other on a 2-core machine.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::OnceLock;

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
    let Some(results) = boot(&[(name, timeout_s)], None) else {
        return false;
    };
    assert_passed(&results, name);
    true
}

/// The VM tests of one test binary that share a boot. A TCG boot of the
/// guest costs tens of seconds of CI time before a test starts, so a
/// binary with several VM tests declares them once and runs them in one
/// VM, each still in its own process, in the order given. The first of
/// them the host harness reaches boots the VM; the others wait for it and
/// read their own result. Every test of the batch runs, whatever filter
/// the host run was given.
pub struct VmBatch {
    /// Test name and its own time limit inside the VM, in seconds.
    tests: &'static [(&'static str, u32)],
    /// Guest RAM when the default (vmrun's 1 GiB) is not enough.
    mem_mb: Option<u32>,
    results: OnceLock<Option<Results>>,
}

impl VmBatch {
    pub const fn new(tests: &'static [(&'static str, u32)]) -> Self {
        Self {
            tests,
            mem_mb: None,
            results: OnceLock::new(),
        }
    }

    /// The same batch in a guest with `mem_mb` of RAM.
    pub const fn with_mem_mb(mut self, mem_mb: u32) -> Self {
        self.mem_mb = Some(mem_mb);
        self
    }

    /// Runs the batch inside the VM (once per process) and asserts test
    /// `name` passed there. Returns false when no VM can run here (see
    /// [`run_test_in_vm`]).
    pub fn run(&self, name: &str) -> bool {
        assert!(
            self.tests.iter().any(|(t, _)| *t == name),
            "{name} is not in its binary's VmBatch"
        );
        match self.results.get_or_init(|| boot(self.tests, self.mem_mb)) {
            Some(results) => {
                assert_passed(results, name);
                true
            }
            None => false,
        }
    }

    /// [`rerun_with_bins`] for a batch: on the host names the programs,
    /// runs the batch and returns true; inside the VM returns false.
    pub fn rerun_with_bins(&self, name: &str) -> bool {
        if in_vm() {
            return false;
        }
        crate::dbus::export_bins();
        self.run(name);
        true
    }
}

/// Each test's exit status inside the VM (`None`: it never finished), and
/// how the VM itself ended.
struct Results {
    exits: Vec<(String, Option<i32>)>,
    vm_status: std::process::ExitStatus,
    timeout_s: u32,
}

/// A line the guest prints after each test, alone on its line.
const RESULT_MARK: &str = "SDI-VM-TEST-EXIT";

/// Boots one VM that runs `tests` of the current test binary one after the
/// other, each in its own process under its own time limit, and collects
/// their exit statuses (`mem_mb`: guest RAM, else vmrun's default). None when no VM can run here.
fn boot(tests: &[(&str, u32)], mem_mb: Option<u32>) -> Option<Results> {
    if let Some(reason) = unavailable_reason() {
        let names: Vec<&str> = tests.iter().map(|(n, _)| *n).collect();
        assert!(
            std::env::var_os("SDI_REQUIRE_VM").is_none(),
            "VM test {names:?} cannot run and SDI_REQUIRE_VM is set: {reason}"
        );
        for name in names {
            crate::skipped!("SKIPPED (no VM): {name}: {reason}");
        }
        return None;
    }
    let exe = std::env::current_exe().expect("test binary path");
    // The guest's loop: `timeout` per test, then the mark on a line of its
    // own (the test's output may not end in a newline).
    let script = format!(
        r#"exe=$1; shift
while [ $# -gt 1 ]; do
  timeout -s KILL "$2" "$exe" --exact "$1" --nocapture --test-threads=1
  printf '\n{RESULT_MARK} %s %s\n' "$1" "$?"
  shift 2
done"#
    );
    // The VM's limit: every test's own, plus the boot.
    let timeout_s = tests.iter().map(|(_, t)| t).sum::<u32>() + 120;
    let mut child = Command::new("flock")
        // Wait at most 30 min for other VM tests; vmrun itself enforces
        // the timeout (exit 124) and kills QEMU on any exit path.
        .args(["-w", "1800", "-E", "75"])
        .arg(std::env::temp_dir().join("sdi-vm.lock"))
        .arg(vmrun_path())
        .args(["-s", "2", "-t", &timeout_s.to_string(), "-e", "IN_VM=1"])
        .args(mem_mb.map(|mb| format!("-m{mb}")))
        .arg("--")
        .args(["bash", "-c", &script, "sdi-vm-tests"])
        .arg(&exe)
        .args(
            tests
                .iter()
                .flat_map(|(n, t)| [n.to_string(), t.to_string()]),
        )
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn vmrun");
    let mut exits: Vec<(String, Option<i32>)> =
        tests.iter().map(|(n, _)| (n.to_string(), None)).collect();
    let stdout = child.stdout.take().expect("piped stdout");
    // The guest's output goes on to this process's own stdout (not the
    // harness's capture), as it would with an inherited descriptor.
    let mut echo = std::io::stdout();
    for line in BufReader::new(stdout).split(b'\n').map_while(Result::ok) {
        let _ = echo.write_all(&line);
        let _ = echo.write_all(b"\n");
        let text = String::from_utf8_lossy(&line);
        if let Some(rest) = text.strip_prefix(RESULT_MARK) {
            let mut words = rest.split_whitespace();
            if let (Some(name), Some(code)) = (words.next(), words.next()) {
                if let Some(slot) = exits.iter_mut().find(|(n, _)| n == name) {
                    slot.1 = code.parse().ok();
                }
            }
        }
    }
    let vm_status = child.wait().expect("wait for vmrun");
    Some(Results {
        exits,
        vm_status,
        timeout_s,
    })
}

fn assert_passed(results: &Results, name: &str) {
    let exit = results
        .exits
        .iter()
        .find(|(n, _)| n == name)
        .and_then(|(_, code)| *code);
    assert!(
        exit == Some(0),
        "{name} failed inside the VM (exit {exit:?}; 137 = killed at its time limit; \
         none = it never finished: the VM ended {status}, 124 = VM timeout after {t} s, \
         125 = VM died (console tail above), 75 = waited 30 min for the VM lock)",
        status = results.vm_status,
        t = results.timeout_s,
    );
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
