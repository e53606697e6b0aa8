//! Helpers for the v4l2loopback VM tests and bench: module loading, a
//! background writer, the ffmpeg reader in the node's format, v4l2-compliance.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use v4l2loopback_glue::{GlueError, LoopbackFormat, LoopbackWriter};

/// Which v4l2loopback build a VM test loads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModuleBuild {
    /// Debian 12's 0.12.7 from DKMS: what a plain `modprobe v4l2loopback` loads.
    Debian0127,
    /// Debian trixie's 0.15.0, built out of tree by `tests/vm/setup-host.sh`
    /// into [`V15_DIR`] (never into /lib/modules).
    V0150,
}

/// Where `setup-host.sh` installs the 0.15.0 module, per kernel version.
pub const V15_DIR: &str = "/var/lib/sdi-test/v4l2loopback-0.15.0";

impl ModuleBuild {
    /// The version string the loaded module reports (`None`: Debian's 0.12.7
    /// build has no MODULE_VERSION).
    pub fn version(self) -> Option<&'static str> {
        match self {
            Self::Debian0127 => None,
            Self::V0150 => Some("0.15.0"),
        }
    }

    /// The out-of-tree `.ko` for kernel `kver` (`None` for the DKMS build).
    pub fn ko_path(self, kver: &str) -> Option<PathBuf> {
        match self {
            Self::Debian0127 => None,
            Self::V0150 => Some(Path::new(V15_DIR).join(kver).join("v4l2loopback.ko")),
        }
    }
}

impl std::fmt::Display for ModuleBuild {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Debian0127 => "v4l2loopback 0.12.7 (Debian 12, DKMS)",
            Self::V0150 => "v4l2loopback 0.15.0 (out of tree)",
        })
    }
}

/// Why loading or unloading the module failed.
#[derive(Debug)]
pub enum ModuleError {
    /// The out-of-tree module was never built for this kernel.
    NotBuilt { build: ModuleBuild, path: PathBuf },
    /// A command (modprobe, insmod, rmmod) failed.
    Command { command: String, detail: String },
    /// The module is still loaded (nodes held open?) after rmmod.
    StillLoaded,
    /// Loaded, but it reports another version than asked for.
    WrongVersion {
        build: ModuleBuild,
        found: Option<String>,
    },
}

impl std::fmt::Display for ModuleError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NotBuilt { build, path } => write!(
                f,
                "{build}: {} is missing; build it with: sudo tests/vm/setup-host.sh",
                path.display()
            ),
            Self::Command { command, detail } => write!(f, "`{command}` failed: {detail}"),
            Self::StillLoaded => {
                f.write_str("v4l2loopback is still loaded after rmmod (a node is still open?)")
            }
            Self::WrongVersion { build, found } => {
                write!(f, "asked for {build}, the loaded module reports {found:?}")
            }
        }
    }
}

impl std::error::Error for ModuleError {}

/// Parameters of a module load: one node per (video_nr, label).
#[derive(Clone, Debug, Default)]
pub struct ModuleParams {
    pub nodes: Vec<(u32, String)>,
    /// exclusive_caps=1 for every node (browsers list only such nodes).
    pub exclusive_caps: bool,
    /// Extra `name=value` parameters (e.g. `max_buffers=4`).
    pub extra: Vec<String>,
}

impl ModuleParams {
    /// Nodes with exclusive_caps=1.
    pub fn nodes(nodes: &[(u32, &str)]) -> Self {
        Self {
            nodes: nodes.iter().map(|(n, l)| (*n, (*l).to_owned())).collect(),
            exclusive_caps: true,
            extra: Vec::new(),
        }
    }

    /// The `name=value` arguments for modprobe / insmod.
    pub fn args(&self) -> Vec<String> {
        let mut args = vec![format!("devices={}", self.nodes.len())];
        if !self.nodes.is_empty() {
            let join = |f: &dyn Fn(&(u32, String)) -> String| {
                self.nodes.iter().map(f).collect::<Vec<_>>().join(",")
            };
            args.push(format!("video_nr={}", join(&|(n, _)| n.to_string())));
            args.push(format!("card_label={}", join(&|(_, l)| l.clone())));
            let caps = u8::from(self.exclusive_caps).to_string();
            args.push(format!("exclusive_caps={}", join(&|_| caps.clone())));
        }
        args.extend(self.extra.iter().cloned());
        args
    }
}

fn run_cmd(program: &str, args: &[String]) -> Result<(), ModuleError> {
    let command = format!("{program} {}", args.join(" "));
    let o = Command::new(program)
        .args(args)
        .output()
        .map_err(|e| ModuleError::Command {
            command: command.clone(),
            detail: format!("cannot spawn: {e}"),
        })?;
    if o.status.success() {
        return Ok(());
    }
    Err(ModuleError::Command {
        command,
        detail: format!(
            "{}: {}",
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        ),
    })
}

/// True while v4l2loopback is loaded.
pub fn module_loaded() -> bool {
    Path::new("/sys/module/v4l2loopback").exists()
}

/// Unloads v4l2loopback if it is loaded (VM only: the host cannot load
/// modules, and a real system's module belongs to its owner).
pub fn unload_module() -> Result<(), ModuleError> {
    if !module_loaded() {
        return Ok(());
    }
    run_cmd("rmmod", &["v4l2loopback".to_owned()])?;
    for _ in 0..50 {
        if !module_loaded() {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Err(ModuleError::StillLoaded)
}

/// Replaces whatever v4l2loopback is loaded by `build` with `params`:
/// rmmod, then `modprobe v4l2loopback ...` (0.12.7) or `modprobe videodev`
/// + `insmod <setup-host.sh's .ko> ...` (0.15.0). Checks the loaded version.
pub fn load_module(build: ModuleBuild, params: &ModuleParams) -> Result<(), ModuleError> {
    unload_module()?;
    let args = params.args();
    match build {
        ModuleBuild::Debian0127 => {
            let mut a = vec!["v4l2loopback".to_owned()];
            a.extend(args);
            run_cmd("modprobe", &a)?;
        }
        ModuleBuild::V0150 => {
            let kver = std::fs::read_to_string("/proc/sys/kernel/osrelease").map_err(|e| {
                ModuleError::Command {
                    command: "read /proc/sys/kernel/osrelease".into(),
                    detail: e.to_string(),
                }
            })?;
            let path = build.ko_path(kver.trim()).expect("out-of-tree build");
            if !path.is_file() {
                return Err(ModuleError::NotBuilt { build, path });
            }
            run_cmd("modprobe", &["videodev".to_owned()])?;
            let mut a = vec![path.display().to_string()];
            // insmod, unlike modprobe, passes its arguments on joined by
            // spaces: the kernel splits a value with a space unless quoted.
            a.extend(args.into_iter().map(|arg| match arg.split_once('=') {
                Some((k, v)) if v.contains(' ') => format!("{k}=\"{v}\""),
                _ => arg,
            }));
            run_cmd("insmod", &a)?;
        }
    }
    let found = std::fs::read_to_string("/sys/module/v4l2loopback/version")
        .ok()
        .map(|s| s.trim().to_owned());
    let matches = match build {
        // Debian's DKMS build of 0.12.7 carries no version string
        ModuleBuild::Debian0127 => match found.as_deref() {
            None => true,
            Some(v) => v.starts_with("0.12."),
        },
        ModuleBuild::V0150 => found.as_deref() == build.version(),
    };
    if !matches {
        return Err(ModuleError::WrongVersion { build, found });
    }
    Ok(())
}

/// Loads Debian's v4l2loopback with one node per (video_nr, label),
/// exclusive_caps=1; panics with the reason on failure.
pub fn modprobe(nodes: &[(u32, &str)]) {
    if let Err(e) = load_module(ModuleBuild::Debian0127, &ModuleParams::nodes(nodes)) {
        panic!("loading v4l2loopback failed: {e}");
    }
}

/// `LoopbackWriter::watchers()` as last seen by the writer thread.
const WATCHERS_UNKNOWN: u32 = u32::MAX;

/// A writer thread publishing `frames` (packed in the node's format) in
/// turn at `fps` until stopped,
/// stamped with CLOCK_MONOTONIC (the clock V4L2 timestamps use) and paced
/// to deadlines, so a slow frame does not lower the rate.
pub struct BackgroundWriter {
    stop: Arc<AtomicBool>,
    watchers: Arc<AtomicU32>,
    handle: Option<JoinHandle<Result<u64, GlueError>>>,
}

/// Microseconds of CLOCK_MONOTONIC.
pub fn monotonic_us() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() as u64 * 1_000_000 + t.tv_nsec() as u64 / 1000)
        .unwrap_or(0)
}

impl BackgroundWriter {
    /// Takes a writer opened on this thread (so open errors surface here)
    /// and moves it to a thread.
    pub fn start(mut writer: LoopbackWriter, frames: Vec<Vec<u8>>) -> Self {
        assert!(!frames.is_empty(), "no frames to write");
        let stop = Arc::new(AtomicBool::new(false));
        let watchers = Arc::new(AtomicU32::new(WATCHERS_UNKNOWN));
        let (flag, seen) = (stop.clone(), watchers.clone());
        let cfg = writer.config();
        let handle = std::thread::spawn(move || {
            let period = Duration::from_micros(1_000_000 / u64::from(cfg.fps));
            let mut deadline = Instant::now();
            for frame in frames.iter().cycle() {
                if flag.load(Ordering::Relaxed) {
                    break;
                }
                writer.write(frame, monotonic_us())?;
                seen.store(
                    writer.watchers().unwrap_or(WATCHERS_UNKNOWN),
                    Ordering::Relaxed,
                );
                deadline += period;
                let now = Instant::now();
                if deadline > now {
                    std::thread::sleep(deadline - now);
                } else {
                    deadline = now; // fell behind: do not burst
                }
            }
            Ok(writer.frames_written())
        });
        Self {
            stop,
            watchers,
            handle: Some(handle),
        }
    }

    /// The writer's `watchers()` after its latest frame (`None`: the module
    /// cannot tell).
    pub fn watchers(&self) -> Option<u32> {
        match self.watchers.load(Ordering::Relaxed) {
            WATCHERS_UNKNOWN => None,
            n => Some(n),
        }
    }

    /// Polls [`watchers`](Self::watchers) until it equals `want` or
    /// `timeout` passes; returns the last value seen.
    pub fn wait_watchers(&self, want: Option<u32>, timeout: Duration) -> Option<u32> {
        let t0 = Instant::now();
        loop {
            let seen = self.watchers();
            if seen == want || t0.elapsed() > timeout {
                return seen;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Stops the thread; returns frames written or the writer's error.
    pub fn stop(mut self) -> Result<u64, GlueError> {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .take()
            .expect("joined once")
            .join()
            .expect("writer thread panicked")
    }
}

impl Drop for BackgroundWriter {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Reads `frames` frames from `dev` with ffmpeg, raw bytes in the node's own
/// pixel format (no conversion).
pub fn ffmpeg_read(
    dev: &Path,
    cfg: &LoopbackFormat,
    frames: u32,
    out: &Path,
) -> Result<Vec<u8>, String> {
    crate::capture::read_frames(dev, frames, cfg.format.ffmpeg_name(), out)
}

/// v4l2-compliance totals.
#[derive(Debug, Clone)]
pub struct Compliance {
    pub total: u32,
    pub succeeded: u32,
    pub failed: u32,
    pub warnings: u32,
    pub failing_tests: Vec<String>,
    /// v4l2-compliance's `fail: <source>(<line>): <check>` lines: why.
    pub fail_reasons: Vec<String>,
    pub output: String,
}

/// Runs `v4l2-compliance -d dev` and parses its summary.
pub fn compliance(dev: &Path) -> Result<Compliance, String> {
    let o = Command::new("timeout")
        .args(["120", "v4l2-compliance", "-d"])
        .arg(dev)
        .output()
        .map_err(|e| format!("spawn v4l2-compliance: {e}"))?;
    let output =
        String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    let line = output
        .lines()
        .find(|l| l.starts_with("Total for"))
        .ok_or_else(|| format!("no summary in v4l2-compliance output:\n{output}"))?;
    let num = |key: &str| -> u32 {
        line.split(key)
            .nth(1)
            .and_then(|s| s.trim().split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|s| s.parse().ok())
            .unwrap_or(u32::MAX)
    };
    let total = line
        .split(": ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(u32::MAX);
    let failing_tests = output
        .lines()
        .filter(|l| l.trim_end().ends_with(": FAIL"))
        .map(|l| l.trim().to_owned())
        .collect();
    let fail_reasons = output
        .lines()
        .filter(|l| l.trim_start().starts_with("fail:"))
        .map(|l| l.trim().to_owned())
        .collect();
    Ok(Compliance {
        total,
        succeeded: num("Succeeded:"),
        failed: num("Failed:"),
        warnings: num("Warnings:"),
        failing_tests,
        fail_reasons,
        output,
    })
}

/// `v4l2-ctl -D` device caps section mentions Video Capture.
pub fn advertises_capture(dev: &Path) -> bool {
    let o = Command::new("v4l2-ctl")
        .arg("-d")
        .arg(dev)
        .arg("-D")
        .output();
    let Ok(o) = o else { return false };
    let text = String::from_utf8_lossy(&o.stdout);
    // only the "Device Caps" block (the "Capabilities" block lists both)
    text.split("Device Caps")
        .nth(1)
        .is_some_and(|s| s.contains("Video Capture"))
}
