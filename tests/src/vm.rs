//! Running tests inside the QEMU VM of `tests/vm/vmrun`.
//!
//! Pattern: each VM test binary (`tests/tests/vm_*`) is one [`Guest`]: a
//! table of its tests with their time limits. On the host, the first test
//! that reaches [`Guest::on_host`] boots the guest once, and the guest runs
//! the binary again (`IN_VM=1`) for every test of the table the host run
//! selected, one after the other, each in its own process; every host-side
//! test then reads its own result. Inside the guest the same test does the
//! real work with the real kernel modules (v4l2loopback, dummy_hcd, ...).
//!
//! Each test starts from a known state in the shared guest
//! (`tests/vm/guest-run`): its own PID and mount namespaces with fresh
//! throw-away layers over /tmp, /var, /etc, /root, /home and /usr and a
//! fresh /run, so processes, users, configuration and files it leaves end
//! with it; after it, the USB gadgets it left are removed and the modules
//! it loaded are unloaded. The systemd guest ([`Guest::with_systemd`]) runs
//! its tests without that sandbox (systemd owns the machine there).
//!
//! At most [`vm_slots`] guests run at once on one machine (lock files in
//! the temporary directory), so parallel test binaries do not starve each
//! other.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Guest RAM of the plain guest: vmrun's default.
pub const PLAIN_MEM_MB: u32 = 1024;
/// Guest RAM where browsers run (Chromium and Firefox need more than 1 GiB).
pub const DESKTOP_MEM_MB: u32 = 2560;

/// Where `tests/vm/debian13-root.sh` builds the Debian 13 guest's root
/// (`SDI_DEBIAN13_ROOT` overrides it, for the script and the tests alike).
pub fn debian13_root() -> PathBuf {
    std::env::var_os("SDI_DEBIAN13_ROOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/var/lib/sdi-test/debian13-root"))
}

/// The Debian release a guest's userland and kernel come from.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Userland {
    /// The host's own root (Debian 12 on CI): its kernel, its programs.
    Host,
    /// Debian 13 "trixie", the release users have now: the tree of
    /// [`debian13_root`] with its own kernel 6.12, v4l2loopback 0.15,
    /// systemd 257, PipeWire 1.4, WirePlumber 0.5; the workspace shared in.
    Debian13,
}

/// Names the file that a build of the Debian 13 root under way writes its
/// exit status to when it ends: CI builds the root beside its first
/// guests (`.ci/run`), and a guest on that root waits for it.
pub const DEBIAN13_ROOT_PENDING_ENV: &str = "SDI_DEBIAN13_ROOT_PENDING";
/// A hang guard for that build: 2 minutes alone, longer beside guests.
const DEBIAN13_ROOT_PENDING_LIMIT: Duration = Duration::from_secs(1200);

/// [`debian13_root`], once the build of it under way (if one is: see
/// [`DEBIAN13_ROOT_PENDING_ENV`]) has ended. The build moves the finished
/// root into place before it writes its status, so the root is whole or
/// absent. Every test that uses the root calls this, not `.ci/run`.
pub fn debian13_root_when_built() -> PathBuf {
    if let Some(status_file) = std::env::var_os(DEBIAN13_ROOT_PENDING_ENV).map(PathBuf::from) {
        // Tests run in their package's directory, not where `.ci/run`
        // started: a relative name would be looked for in the wrong place
        // until the guard ran out (CI's run of 0347d4b, 1200 s).
        assert!(
            status_file.is_absolute() && status_file.parent().is_some_and(Path::is_dir),
            "{DEBIAN13_ROOT_PENDING_ENV}={} must name a file in an existing directory, by an absolute path",
            status_file.display()
        );
        let t0 = Instant::now();
        let status = crate::wait::wait_for(
            "the build of the Debian 13 root under way",
            DEBIAN13_ROOT_PENDING_LIMIT,
            || std::fs::read_to_string(&status_file).ok(),
        );
        eprintln!(
            "the Debian 13 root's build ended (exit status, seconds: {}); waited {:.0} s for it",
            status.trim(),
            t0.elapsed().as_secs_f64()
        );
        assert!(
            status.split_whitespace().next() == Some("0"),
            "the build of the Debian 13 root failed (exit status, seconds: {}); its log is beside {}",
            status.trim(),
            status_file.display()
        );
    }
    debian13_root()
}

impl Userland {
    /// Why a guest of this userland cannot boot here, if it cannot.
    fn unavailable_reason(self) -> Option<String> {
        if let Some(reason) = unavailable_reason() {
            return Some(reason);
        }
        if self != Self::Debian13 {
            return None;
        }
        let root = debian13_root_when_built();
        (!root.join("usr").is_dir()).then(|| {
            format!(
                "no Debian 13 guest root at {} (run: sudo tests/vm/debian13-root.sh)",
                root.display()
            )
        })
    }
}

/// True inside the VM.
pub fn in_vm() -> bool {
    std::env::var_os("IN_VM").is_some()
}

/// Path of the launcher script.
pub fn vmrun_path() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/vm/vmrun"))
}

/// Path of the guest's test runner.
fn guest_run_path() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/vm/guest-run"))
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

/// How many guests may run at once on this machine: `SDI_VM_SLOTS`, else 1.
/// A TCG guest keeps about one core busy.
pub fn vm_slots() -> usize {
    std::env::var("SDI_VM_SLOTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&n| n >= 1)
        .unwrap_or(1)
}

/// What the guest boots as PID 1.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Init {
    /// vmrun's busybox init: no udevd, no system bus; each test sandboxed.
    Plain,
    /// The root's systemd (`vmrun -S`): udevd, logind, the system bus.
    Systemd,
}

/// One VM guest and the tests of one test binary that run in it.
pub struct Guest {
    /// Test name (as libtest names it: `module::function`) and its own time
    /// limit inside the guest, in seconds.
    tests: &'static [(&'static str, u32)],
    mem_mb: u32,
    init: Init,
    userland: Userland,
    /// Host-side preparation before the boot: what the guest's tests need
    /// in the environment (programs, packages). The guest's environment is
    /// the host's at boot. False: what the tests need cannot be made here
    /// (it has printed why, or failed under a require flag); no boot.
    prepare: Option<fn() -> bool>,
    /// None: the guest cannot run here.
    results: OnceLock<Option<Results>>,
}

impl Guest {
    /// The plain guest ([`PLAIN_MEM_MB`], busybox init) running `tests`.
    pub const fn new(tests: &'static [(&'static str, u32)]) -> Self {
        Self {
            tests,
            mem_mb: PLAIN_MEM_MB,
            init: Init::Plain,
            userland: Userland::Host,
            prepare: None,
            results: OnceLock::new(),
        }
    }

    /// The same guest with `mem_mb` of RAM.
    pub const fn with_mem_mb(mut self, mem_mb: u32) -> Self {
        self.mem_mb = mem_mb;
        self
    }

    /// The same guest on `userland`'s root and kernel.
    pub const fn on(mut self, userland: Userland) -> Self {
        self.userland = userland;
        self
    }

    /// The same guest booted by its root's systemd (`vmrun -S`).
    pub const fn with_systemd(mut self) -> Self {
        self.init = Init::Systemd;
        self
    }

    /// `prepare` runs on the host once, before the boot; when it returns
    /// false the guest's tests are skipped.
    pub const fn prepared_by(mut self, prepare: fn() -> bool) -> Self {
        self.prepare = Some(prepare);
        self
    }

    /// On the host: runs the calling test in the guest (booting it, once
    /// per process, for every selected test of the table), asserts it
    /// passed there and returns true; prints why and returns true when no
    /// VM can run here (a failure under `SDI_REQUIRE_VM`). Inside the guest
    /// returns false: the caller goes on to do the test's work.
    ///
    /// The test is named by its thread, which libtest names after the test.
    pub fn on_host(&self) -> bool {
        if in_vm() {
            return false;
        }
        let name = current_test();
        assert!(
            self.tests.iter().any(|(t, _)| *t == name),
            "{name} is not in its binary's Guest table"
        );
        let results = self.results.get_or_init(|| {
            if let Some(reason) = self.userland.unavailable_reason() {
                crate::skip::unavailable(
                    "SDI_REQUIRE_VM",
                    format_args!("the VM tests cannot run: {reason}"),
                );
                return None;
            }
            if let Some(prepare) = self.prepare {
                if !prepare() {
                    return None;
                }
            }
            let selected: Vec<(&str, u32)> = self
                .tests
                .iter()
                .filter(|(t, _)| selected_by_args(t))
                .copied()
                .collect();
            Some(self.boot(&selected))
        });
        match results {
            Some(results) => assert_passed(results, &name),
            None => crate::skipped!("SKIPPED: {name}: its guest cannot run here (above)"),
        }
        true
    }

    /// Boots one VM that runs `tests` of the current test binary one after
    /// the other, each in its own process under its own time limit, and
    /// collects their exit statuses.
    fn boot(&self, tests: &[(&str, u32)]) -> Results {
        let exe = std::env::current_exe().expect("test binary path");
        // The VM's limit: every test's own, the guest's resets and the boot.
        let timeout_s = tests.iter().map(|(_, t)| t + 10).sum::<u32>() + 180;
        let _slot = VmSlot::take();
        let mut cmd = Command::new(vmrun_path());
        // /usr writable too (a throw-away layer), for the tests that
        // install the Debian packages with dpkg.
        cmd.env(
            "VMRUN_APPEND",
            "vmrun.overlays=/tmp,/var,/etc,/root,/home,/usr",
        )
        .args(["-s", "2", "-t", &timeout_s.to_string(), "-e", "IN_VM=1"])
        .arg(format!("-m{}", self.mem_mb));
        if self.init == Init::Systemd {
            cmd.arg("-S");
        }
        if self.userland == Userland::Debian13 {
            // The workspace (programs, test binaries, scripts) at the same
            // path, read-only; the target directory too if it lies outside.
            let workspace = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .parent()
                .expect("workspace")
                .to_owned();
            cmd.arg("-r").arg(debian13_root()).arg("-o").arg(&workspace);
            let target = exe.ancestors().nth(3).expect("target directory");
            if !target.starts_with(&workspace) {
                cmd.arg("-o").arg(target);
            }
        }
        let sandbox = match self.init {
            Init::Plain => "sandbox",
            Init::Systemd => "plain",
        };
        cmd.arg("--")
            .arg(guest_run_path())
            .arg(sandbox)
            .arg(&exe)
            .args(
                tests
                    .iter()
                    .flat_map(|(n, t)| [n.to_string(), t.to_string()]),
            )
            .stdout(Stdio::piped());
        let started = Instant::now();
        let mut child = cmd.spawn().expect("spawn vmrun");
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
        let _ = writeln!(
            echo,
            "{BOOT_MARK} {} tests {:.0} s {vm_status}",
            tests.len(),
            started.elapsed().as_secs_f64()
        );
        Results {
            exits,
            vm_status,
            timeout_s,
        }
    }
}

/// A line the guest prints after each test, alone on its line:
/// `SDI-VM-TEST-EXIT NAME STATUS SECONDS`.
const RESULT_MARK: &str = "SDI-VM-TEST-EXIT";
/// The line the host prints after each boot (the CI timing table counts them).
const BOOT_MARK: &str = "SDI-VM-BOOT-DONE";

/// The running test's name: libtest runs each test on a thread named after it.
fn current_test() -> String {
    std::thread::current()
        .name()
        .filter(|n| *n != "main")
        .expect("a test thread named by libtest")
        .to_owned()
}

/// Whether this run of the test binary selects test `name`, by libtest's
/// rules for its arguments: a name matches a filter when it contains it
/// (equals it with `--exact`), and no `--skip` pattern matches. So
/// `cargo test --test vm_plain board::` boots the guest for the `board`
/// tests only.
fn selected_by_args(name: &str) -> bool {
    let mut filters = Vec::new();
    let mut skips = Vec::new();
    let mut exact = false;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--exact" => exact = true,
            "--skip" => skips.extend(args.next()),
            // libtest's options that take a value.
            "--test-threads" | "--format" | "--color" | "--logfile" | "-Z" | "--shuffle-seed" => {
                args.next();
            }
            a if a.starts_with('-') => {}
            a => filters.push(a.to_owned()),
        }
    }
    let matches = |pattern: &str| {
        if exact {
            name == pattern
        } else {
            name.contains(pattern)
        }
    };
    (filters.is_empty() || filters.iter().any(|f| matches(f))) && !skips.iter().any(|s| matches(s))
}

/// One of the machine's [`vm_slots`], held while a guest runs. Waits at
/// most 30 minutes for one.
struct VmSlot {
    /// Held, not read: the slot is free again when it drops.
    _lock: nix::fcntl::Flock<std::fs::File>,
}

impl VmSlot {
    fn take() -> Self {
        let deadline = Instant::now() + Duration::from_secs(1800);
        loop {
            for i in 0..vm_slots() {
                // Slot 0 is the lock the bench scripts take too.
                let name = match i {
                    0 => "sdi-vm.lock".to_owned(),
                    i => format!("sdi-vm.lock.{i}"),
                };
                let path = std::env::temp_dir().join(name);
                let file = std::fs::OpenOptions::new()
                    .create(true)
                    .truncate(false)
                    .write(true)
                    .open(&path)
                    .unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
                if let Ok(lock) =
                    nix::fcntl::Flock::lock(file, nix::fcntl::FlockArg::LockExclusiveNonblock)
                {
                    return Self { _lock: lock };
                }
            }
            assert!(
                Instant::now() < deadline,
                "waited 30 min for a VM slot (another VM test holds every one)"
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }
}

/// Each test's exit status inside the VM (`None`: it never finished), and
/// how the VM itself ended.
struct Results {
    exits: Vec<(String, Option<i32>)>,
    vm_status: std::process::ExitStatus,
    timeout_s: u32,
}

fn assert_passed(results: &Results, name: &str) {
    let Some((_, exit)) = results.exits.iter().find(|(n, _)| n == name) else {
        panic!(
            "{name} was not run in the guest: it was not selected when the guest booted \
             (the guest runs the tests the first VM test's run selects)"
        );
    };
    assert!(
        *exit == Some(0),
        "{name} failed inside the VM (exit {exit:?}; 137 = killed at its time limit; \
         none = it never finished: the VM ended {status}, 124 = VM timeout after {t} s, \
         125 = VM died (console tail above))",
        status = results.vm_status,
        t = results.timeout_s,
    );
}
