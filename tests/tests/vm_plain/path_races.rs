//! The two races of the path methods, attempted against a root sdid by an
//! unprivileged caller (uid 65534 through `setpriv`) on a private bus:
//!
//! 1. a symlink renamed over the new file before the daemon hands it to the
//!    caller (chown by path would give a root-only file away);
//! 2. a parent directory swapped between validation and creation (a file
//!    would land in a root-only directory).
//!
//! Each is tried `SDI_RACE_ATTEMPTS` times (default 1,000), stopping at the
//! first win, which fails the test. On the host the tests need root and are
//! skipped otherwise; `vm_races_against_a_root_sdid_without_systemd` runs
//! both inside the QEMU VM (root, no systemd, no sandbox: as in a container
//! or under `sudo sdid`), whatever the host user.

use std::fs;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use sdi_tests::dbus::{bin, Bus};
use sdi_tests::process::{runnable_copy, Reaped};
use sdi_tests::sdid_command::SdidCommand;
use sdi_tests::{require_dbus, vm};

const CALLER_UID: u32 = 65534;

fn attempts() -> usize {
    std::env::var("SDI_RACE_ATTEMPTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000)
}

/// The sdid and sdictl under test: built here on the host; inside the VM
/// (read-only root, no cargo) the ones the host built and exported.
struct Binaries {
    sdictl: PathBuf,
}

impl Binaries {
    fn here() -> Self {
        Self {
            sdictl: bin("sdictl"),
        }
    }
}

/// How the attacker calls `Snapshot(path)`.
enum Client {
    /// `sdictl snapshot --by-path`, a process per attempt (on the host).
    Sdictl,
    /// One `path_caller` process for every attempt (in the VM, where a
    /// process start under TCG costs far more than the call).
    Persistent {
        _child: Reaped,
        stdin: ChildStdin,
        stdout: BufReader<ChildStdout>,
    },
}

struct Setup {
    _dir: tempfile::TempDir,
    root: PathBuf,
    _bus: Bus,
    _sdid: Reaped,
    address: String,
    sdictl: PathBuf,
    client: Client,
}

impl Setup {
    fn new() -> Self {
        let dir = tempfile::Builder::new()
            .prefix("sdi-race-")
            .tempdir_in("/var/tmp")
            .unwrap();
        let root = dir.path().to_owned();
        fs::set_permissions(&root, fs::Permissions::from_mode(0o755)).unwrap();
        // The state directory: owned by the caller (the worst case: the
        // attacker may rename anything in it).
        let state = root.join("state");
        fs::create_dir(&state).unwrap();
        std::os::unix::fs::chown(&state, Some(CALLER_UID), Some(CALLER_UID)).unwrap();
        // Root-only: a victim file and a directory nobody else may write.
        let secret = root.join("root-only");
        fs::create_dir(&secret).unwrap();
        fs::set_permissions(&secret, fs::Permissions::from_mode(0o700)).unwrap();
        fs::write(secret.join("victim"), b"root's").unwrap();
        // The caller's own directory.
        let user = root.join("user");
        fs::create_dir(&user).unwrap();
        std::os::unix::fs::chown(&user, Some(CALLER_UID), Some(CALLER_UID)).unwrap();
        let bus = Bus::start_open(&root);
        let address = bus.address.clone();
        let bins = Binaries::here();
        // Under TCG the small sensor at a lower rate leaves the VM's two
        // CPUs to the caller and the attacker.
        let (fps, sensor): (&str, &[&str]) = if vm::in_vm() {
            ("15", &["--sensor", "pmd"])
        } else {
            ("60", &[])
        };
        let sdid = SdidCommand::new()
            .bus(&address)
            .sim()
            .y4m("-")
            .args(["--frame-rate-hz", fps])
            .args(sensor)
            .state_dir(&state)
            .command()
            .stdout(Stdio::null())
            .spawn()
            .expect("start sdid");
        let sdictl = runnable_copy(&bins.sdictl, &root.join("bin"));
        let mut s = Self {
            _dir: dir,
            root,
            _bus: bus,
            _sdid: Reaped(sdid),
            address,
            sdictl,
            client: Client::Sdictl,
        };
        let start = Instant::now();
        while !s.as_caller(&["get", "mode"]).status.success() {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "sdid did not come up"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        if vm::in_vm() {
            s.client = s.persistent_client();
        }
        s
    }

    /// `path_caller` on the test bus as uid 65534.
    fn persistent_client(&self) -> Client {
        let program = runnable_copy(
            Path::new(env!("CARGO_BIN_EXE_path_caller")),
            &self.root.join("bin"),
        );
        let uid = CALLER_UID.to_string();
        let mut child = Command::new("setpriv")
            .args(["--reuid", &uid, "--regid", &uid, "--clear-groups"])
            .arg(program)
            .arg(&self.address)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("run setpriv path_caller");
        let stdin = child.stdin.take().expect("path_caller stdin");
        let stdout = BufReader::new(child.stdout.take().expect("path_caller stdout"));
        Client::Persistent {
            _child: Reaped(child),
            stdin,
            stdout,
        }
    }

    /// `Snapshot(path)` as uid 65534; true when the daemon wrote it.
    fn snapshot_by_path(&mut self, path: &Path) -> bool {
        let path = path.to_str().expect("a UTF-8 test path");
        match &mut self.client {
            Client::Sdictl => self
                .as_caller(&["snapshot", "--by-path", path])
                .status
                .success(),
            Client::Persistent { stdin, stdout, .. } => {
                writeln!(stdin, "{path}").expect("write to path_caller");
                let mut reply = String::new();
                stdout.read_line(&mut reply).expect("read path_caller");
                assert!(!reply.is_empty(), "path_caller exited");
                reply.trim() == "ok"
            }
        }
    }

    /// sdictl on the test bus as uid 65534.
    fn as_caller(&self, args: &[&str]) -> std::process::Output {
        let uid = CALLER_UID.to_string();
        Command::new("setpriv")
            .args(["--reuid", &uid, "--regid", &uid, "--clear-groups"])
            .arg(&self.sdictl)
            .args(["--bus-address", &self.address])
            .args(args)
            .output()
            .expect("run setpriv sdictl")
    }

    fn state(&self) -> PathBuf {
        self.root.join("state")
    }

    fn secret(&self) -> PathBuf {
        self.root.join("root-only")
    }
}

fn skip() -> bool {
    if !sdi_tests::process::is_root() {
        sdi_tests::skipped!("SKIPPED: the races need a root sdid (run as root)");
        return true;
    }
    if Command::new("setpriv").arg("--version").output().is_err() {
        sdi_tests::skipped!("SKIPPED: setpriv is not installed (apt-get install util-linux)");
        return true;
    }
    false
}

#[test]
fn symlink_over_the_new_file_never_gives_a_root_file_away() {
    require_dbus!();
    if skip() {
        return;
    }
    race_symlink_over_the_new_file();
}

#[test]
fn swapping_the_parent_never_creates_a_file_in_a_root_only_directory() {
    require_dbus!();
    if skip() {
        return;
    }
    race_parent_swap();
}

/// Both races against a root sdid in the VM: no systemd, no unit sandbox,
/// all capabilities (CAP_CHOWN included), the attacker an unprivileged uid.
#[test]
fn vm_races_against_a_root_sdid_without_systemd() {
    if crate::GUEST.on_host() {
        return;
    }
    require_dbus!();
    assert!(!skip(), "the VM runs the test as root, with setpriv");
    // No systemd in the guest: PID 1 is the VM's own init.
    let init = fs::read_to_string("/proc/1/comm").unwrap_or_default();
    assert!(!init.trim().contains("systemd"), "PID 1 is {init}");
    let t = Instant::now();
    race_symlink_over_the_new_file();
    eprintln!("race 1 in the VM: {:.0} s", t.elapsed().as_secs_f64());
    let t = Instant::now();
    race_parent_swap();
    eprintln!("race 2 in the VM: {:.0} s", t.elapsed().as_secs_f64());
}

fn race_symlink_over_the_new_file() {
    let mut s = Setup::new();
    let victim = s.secret().join("victim");
    let state = s.state();
    let current = Arc::new(AtomicUsize::new(usize::MAX));
    let stop = Arc::new(AtomicBool::new(false));
    let swapped = Arc::new(AtomicUsize::new(0));
    // The attacker: as soon as the daemon's new file appears, rename a
    // symlink to the victim over it.
    let racer = {
        let (current, stop, swapped) = (current.clone(), stop.clone(), swapped.clone());
        let (state, victim) = (state.clone(), victim.clone());
        std::thread::spawn(move || {
            let tmp = state.join(".link");
            let mut done = usize::MAX;
            while !stop.load(Ordering::Relaxed) {
                let i = current.load(Ordering::Relaxed);
                if i == done || i == usize::MAX {
                    // Nothing in flight: leave the CPU to the daemon.
                    std::thread::yield_now();
                    continue;
                }
                let target = state.join(format!("x{i}.npy"));
                if target
                    .symlink_metadata()
                    .is_ok_and(|m| m.file_type().is_file())
                {
                    let _ = fs::remove_file(&tmp);
                    if std::os::unix::fs::symlink(&victim, &tmp).is_ok()
                        && fs::rename(&tmp, &target).is_ok()
                    {
                        swapped.fetch_add(1, Ordering::Relaxed);
                    }
                    done = i;
                }
            }
        })
    };
    let n = attempts();
    let (mut tried, mut ok, mut refused) = (0, 0, 0);
    let mut won = None;
    for i in 0..n {
        current.store(i, Ordering::Relaxed);
        let path = state.join(format!("x{i}.npy"));
        tried += 1;
        if s.snapshot_by_path(&path) {
            ok += 1;
        } else {
            refused += 1;
        }
        if fs::metadata(&victim).unwrap().uid() != 0 {
            won = Some(i);
            break;
        }
    }
    stop.store(true, Ordering::Relaxed);
    racer.join().unwrap();
    let swapped = swapped.load(Ordering::Relaxed);
    eprintln!(
        "race 1 (symlink before chown): {tried} attempts, {ok} snapshots written, \
         {refused} refused, {swapped} symlinks renamed over a new file, won: {won:?}"
    );
    assert_eq!(won, None, "the victim was handed to uid {CALLER_UID}");
    assert_eq!(fs::read(&victim).unwrap(), b"root's");
    assert!(ok > 0, "no snapshot was ever written: the race was not run");
    // The files the attacker left alone were handed to the caller.
    let handed = fs::read_dir(&state)
        .unwrap()
        .filter_map(Result::ok)
        .filter_map(|e| e.path().symlink_metadata().ok())
        .filter(|m| m.file_type().is_file() && m.uid() == CALLER_UID)
        .count();
    eprintln!("race 1: {handed} new files left in place, owned by uid {CALLER_UID}");
    assert!(
        handed + swapped >= ok,
        "{handed} handed + {swapped} swapped < {ok} written"
    );
}

fn race_parent_swap() {
    let mut s = Setup::new();
    let state = s.state();
    let (user, secret) = (s.root.join("user"), s.secret());
    let stop = Arc::new(AtomicBool::new(false));
    let flips = Arc::new(AtomicUsize::new(0));
    // The attacker: `state/sub` flips between the caller's own directory
    // and the root-only one.
    let racer = {
        let (stop, flips) = (stop.clone(), flips.clone());
        let (state, user, secret) = (state.clone(), user.clone(), secret.clone());
        std::thread::spawn(move || {
            let (sub, tmp) = (state.join("sub"), state.join(".sub"));
            let mut k = 0usize;
            while !stop.load(Ordering::Relaxed) {
                let to = if k.is_multiple_of(2) { &user } else { &secret };
                let _ = fs::remove_file(&tmp);
                if std::os::unix::fs::symlink(to, &tmp).is_ok() && fs::rename(&tmp, &sub).is_ok() {
                    k += 1;
                }
            }
            flips.store(k, Ordering::Relaxed);
        })
    };
    let n = attempts();
    let (mut tried, mut ok, mut refused) = (0, 0, 0);
    let mut won = None;
    let landed = |dir: &Path| {
        fs::read_dir(dir)
            .unwrap()
            .filter_map(Result::ok)
            .any(|e| e.file_name().to_string_lossy().starts_with('y'))
    };
    for i in 0..n {
        let path = state.join("sub").join(format!("y{i}.npy"));
        tried += 1;
        if s.snapshot_by_path(&path) {
            ok += 1;
        } else {
            refused += 1;
        }
        if landed(&secret) {
            won = Some(i);
            break;
        }
    }
    stop.store(true, Ordering::Relaxed);
    racer.join().unwrap();
    eprintln!(
        "race 2 (parent swap): {tried} attempts, {ok} snapshots written (into the caller's \
         directory), {refused} refused, {} parent flips, won: {won:?}",
        flips.load(Ordering::Relaxed)
    );
    assert_eq!(won, None, "a file was created in the root-only directory");
}
