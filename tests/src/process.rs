//! Small process helpers shared by the integration tests.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};

use nix::sys::signal::Signal;
use nix::unistd::Pid;

/// The workspace root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace root")
        .to_path_buf()
}

/// Kills and reaps a child process when dropped: the tests' one guard
/// against a failing test leaving processes behind.
pub struct Reaped(pub Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Sends `sig` to the process `pid` (a child of the test, or one it
/// started); a process that is already gone is no error.
pub fn signal(pid: u32, sig: Signal) {
    let _ = nix::sys::signal::kill(nix_pid(pid), sig);
}

/// Whether the process `pid` exists (signal 0 checks without sending).
pub fn exists(pid: u32) -> bool {
    nix::sys::signal::kill(nix_pid(pid), None).is_ok()
}

/// `std::process::Child::id`'s pid as nix takes it.
fn nix_pid(pid: u32) -> Pid {
    Pid::from_raw(i32::try_from(pid).expect("a pid fits in pid_t"))
}

/// Whether the test runs as root.
pub fn is_root() -> bool {
    nix::unistd::geteuid().is_root()
}

/// Runs `cmd`, echoing the command, its status and output to stderr.
pub fn run(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("spawn {cmd:?}: {e}"));
    eprintln!(
        "$ {cmd:?} -> {}\n{}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Like [`run`], and asserts that the command succeeded.
pub fn must(cmd: &mut Command) -> Output {
    let out = run(cmd);
    assert!(out.status.success(), "{cmd:?} failed ({})", out.status);
    out
}

/// Asserts that a finished command succeeded (its stderr in the message)
/// and returns its stdout as text.
pub fn stdout_of(out: &Output) -> String {
    assert!(
        out.status.success(),
        "status {:?}: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A copy of the program at `path` in `dir` (created), both mode 0755, so
/// another user can run it wherever the checkout lives (a 0700 parent, as
/// `mktemp -d` makes, hides the build from everybody but its owner).
pub fn runnable_copy(path: &std::path::Path, dir: &std::path::Path) -> std::path::PathBuf {
    use std::os::unix::fs::PermissionsExt;
    std::fs::create_dir_all(dir).expect("mkdir for the copy");
    let name = path.file_name().expect("a program file name");
    let copy = dir.join(name);
    std::fs::copy(path, &copy).expect("copy the program");
    for p in [dir, copy.as_path()] {
        std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o755)).expect("chmod 755");
    }
    copy
}
