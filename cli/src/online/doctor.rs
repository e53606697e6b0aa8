//! `sdictl doctor`: what users of virtual cameras hit most, checked in one
//! command, with the fix printed for each failing item.
//!
//! Checks, in order: the v4l2loopback module (installed, loaded, version);
//! Secure Boot / lockdown and whether the module is signed (the "Key was
//! rejected by service" case); the SDI nodes (present, `exclusive_caps`,
//! enough buffers); the caller's groups (`sdi`, `video`); the daemon
//! (reachable, on which bus); the board (attached, USB mode and speed);
//! PipeWire (running, which SDI nodes it lists and whether each can be
//! read: `pipewire.rs`). Exit status 0 only when no
//! check fails; warnings do not block.
//!
//! Everything is read from sysfs/procfs under `--sysroot` (default `/`, a
//! test points it at a fake tree) and from `modinfo`, `id` and `pw-dump`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value as Json};

use super::BusArgs;
use crate::stdout::outln;

mod pipewire;

/// Outcome of one check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    Ok,
    /// Works, but worth knowing (does not block).
    Warn,
    /// Blocks using the camera.
    Fail,
    /// Not applicable here.
    Skip,
}

impl Status {
    fn tag(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Warn => "warn",
            Status::Fail => "FAIL",
            Status::Skip => "skip",
        }
    }
}

/// One line of the report.
#[derive(Clone, Debug)]
pub struct Check {
    pub id: &'static str,
    pub status: Status,
    pub summary: String,
    pub fix: Option<String>,
}

impl Check {
    fn new(id: &'static str, status: Status, summary: impl Into<String>) -> Self {
        Self {
            id,
            status,
            summary: summary.into(),
            fix: None,
        }
    }

    fn fix(mut self, fix: impl Into<String>) -> Self {
        self.fix = Some(fix.into());
        self
    }

    fn json(&self) -> Json {
        json!({
            "id": self.id,
            "status": self.status.tag().to_lowercase(),
            "summary": self.summary,
            "fix": self.fix,
        })
    }
}

/// Where sysfs and procfs are read from.
struct Sys {
    root: PathBuf,
}

impl Sys {
    fn path(&self, p: &str) -> PathBuf {
        self.root.join(p.trim_start_matches('/'))
    }

    fn read(&self, p: &str) -> Option<String> {
        std::fs::read_to_string(self.path(p))
            .ok()
            .map(|s| s.trim().to_owned())
    }

    fn exists(&self, p: &str) -> bool {
        self.path(p).exists()
    }
}

/// Runs `program args` with a time limit; its stdout when it succeeded.
fn output(program: &str, args: &[&str], limit: Duration) -> Option<String> {
    let mut child = Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .ok()?;
    let mut stdout = child.stdout.take()?;
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut stdout, &mut s);
        s
    });
    let t0 = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break Some(s),
            Ok(None) if t0.elapsed() < limit => std::thread::sleep(Duration::from_millis(20)),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
        }
    };
    let text = reader.join().ok()?;
    status.filter(|s| s.success()).map(|_| text)
}

fn modinfo(field: &str) -> Option<String> {
    output(
        "modinfo",
        &["-F", field, "v4l2loopback"],
        Duration::from_secs(5),
    )
    .map(|s| s.trim().to_owned())
}

/// The module's state, as the checks need it.
#[derive(Debug, Default)]
struct Module {
    installed: bool,
    loaded: bool,
    version: Option<String>,
    /// Signer of the installed .ko (modinfo), if signed.
    signer: Option<String>,
    /// The loaded module's taint flags ("E": unsigned, "O": out of tree).
    taint: Option<String>,
}

fn module(sys: &Sys) -> Module {
    let filename = modinfo("filename");
    let loaded = sys.exists("/sys/module/v4l2loopback");
    let version = sys
        .read("/sys/module/v4l2loopback/version")
        .or_else(|| modinfo("version"))
        .filter(|v| !v.is_empty());
    Module {
        installed: filename.is_some() || loaded,
        loaded,
        version,
        signer: modinfo("signer").filter(|s| !s.is_empty()),
        taint: sys.read("/sys/module/v4l2loopback/taint"),
    }
}

fn check_module(m: &Module) -> Check {
    let version = m
        .version
        .as_deref()
        .unwrap_or("0.12.x or older (no version string)");
    match (m.installed, m.loaded) {
        (_, true) => Check::new("module", Status::Ok, format!("v4l2loopback {version} loaded")),
        (true, false) => Check::new("module", Status::Fail, format!("v4l2loopback {version} installed but not loaded"))
            .fix("sudo modprobe v4l2loopback (its options come from /etc/modprobe.d/sdi.conf, which `make install` puts there); to load it at boot: /etc/modules-load.d/sdi.conf"),
        (false, false) => Check::new("module", Status::Fail, "v4l2loopback is not installed for this kernel")
            .fix("sudo apt install v4l2loopback-dkms linux-headers-$(uname -r) (Debian/Ubuntu; other distributions: their v4l2loopback package), then sudo modprobe v4l2loopback"),
    }
}

/// Secure Boot state from the EFI variable: None without EFI.
fn secure_boot(sys: &Sys) -> Option<bool> {
    let dir = sys.path("/sys/firmware/efi/efivars");
    let entries = std::fs::read_dir(dir).ok()?;
    for e in entries.flatten() {
        if e.file_name().to_string_lossy().starts_with("SecureBoot-") {
            // 4 bytes of attributes, then the value
            let bytes = std::fs::read(e.path()).ok()?;
            return bytes.get(4).map(|&b| b == 1);
        }
    }
    sys.exists("/sys/firmware/efi").then_some(false)
}

/// The selected lockdown mode (`[none] integrity confidentiality`).
fn lockdown(sys: &Sys) -> Option<String> {
    let text = sys.read("/sys/kernel/security/lockdown")?;
    let start = text.find('[')?;
    let end = text[start..].find(']')?;
    Some(text[start + 1..start + end].to_owned())
}

const MOK_STEPS: &str = "modprobe fails with \"Key was rejected by service\" when Secure Boot is on and the module is not signed by a key the firmware trusts. DKMS signs the modules it builds with its own key; enrol that key once: sudo mokutil --import /var/lib/dkms/mok.pub (choose a one-time password), reboot, pick \"Enroll MOK\" in the blue MokManager screen and type that password; then sudo dkms autoinstall (or reinstall v4l2loopback-dkms) and sudo modprobe v4l2loopback. Check with: mokutil --test-key /var/lib/dkms/mok.pub";

/// The Secure Boot / lockdown / signature verdict (pure, unit-tested).
fn signature_verdict(sb: Option<bool>, lockdown: Option<&str>, m: &Module) -> Check {
    let sb_text = match sb {
        Some(true) => "Secure Boot on",
        Some(false) => "Secure Boot off",
        None => "no EFI (no Secure Boot)",
    };
    let lock = lockdown.unwrap_or("none");
    let enforced = sb == Some(true) || lock != "none";
    let state = format!("{sb_text}, lockdown {lock}");
    if m.loaded {
        let unsigned = m.taint.as_deref().is_some_and(|t| t.contains('E'));
        let sig = if unsigned {
            "unsigned"
        } else {
            "signature accepted"
        };
        return Check::new(
            "secure-boot",
            Status::Ok,
            format!("{state}; the loaded module: {sig}"),
        );
    }
    if !m.installed {
        return Check::new(
            "secure-boot",
            Status::Skip,
            format!("{state}; no module to check"),
        );
    }
    match (&m.signer, enforced) {
        (None, true) => Check::new(
            "secure-boot",
            Status::Fail,
            format!("{state}, and the v4l2loopback module is not signed: the kernel will refuse it"),
        )
        .fix(MOK_STEPS),
        (Some(signer), true) => Check::new(
            "secure-boot",
            Status::Warn,
            format!("{state}; the module is signed by \"{signer}\": it loads only if that key is enrolled"),
        )
        .fix(MOK_STEPS),
        (signer, false) => Check::new(
            "secure-boot",
            Status::Ok,
            format!(
                "{state}; module {}",
                signer
                    .as_ref()
                    .map_or("unsigned (fine without Secure Boot)".to_owned(), |s| format!("signed by \"{s}\""))
            ),
        ),
    }
}

/// A v4l2loopback node: number, label and its module parameters.
#[derive(Debug, Clone, PartialEq)]
struct Node {
    nr: u32,
    label: String,
    /// `exclusive_caps` of this node, when it was created by the module's
    /// parameters (not at run time through /dev/v4l2loopback).
    exclusive_caps: Option<bool>,
}

/// Per-node module parameter: the i-th entry of the comma list belongs to
/// the i-th `video_nr`.
fn param_for(video_nr: &str, values: &str, nr: u32) -> Option<String> {
    let i = video_nr
        .split(',')
        .position(|v| v.trim().parse::<i64>().ok() == Some(i64::from(nr)))?;
    values.split(',').nth(i).map(|s| s.trim().to_owned())
}

fn loopback_nodes(sys: &Sys) -> Vec<Node> {
    let mut nodes = Vec::new();
    let Ok(entries) = std::fs::read_dir(sys.path("/sys/class/video4linux")) else {
        return nodes;
    };
    let video_nr = sys
        .read("/sys/module/v4l2loopback/parameters/video_nr")
        .unwrap_or_default();
    let caps = sys
        .read("/sys/module/v4l2loopback/parameters/exclusive_caps")
        .unwrap_or_default();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(nr) = name
            .strip_prefix("video")
            .and_then(|n| n.parse::<u32>().ok())
        else {
            continue;
        };
        // only v4l2loopback's nodes: virtual (0.12.x registers them with no
        // parent device) or on a v4l2loopback platform device
        let driver = std::fs::read_link(e.path().join("device/driver"))
            .ok()
            .and_then(|p| p.file_name().map(|f| f.to_string_lossy().into_owned()));
        let virtual_node = !e.path().join("device").exists();
        if !virtual_node && driver.as_deref() != Some("v4l2loopback") {
            continue;
        }
        let label = sys
            .read(&format!("/sys/class/video4linux/{name}/name"))
            .unwrap_or_default();
        let exclusive_caps = param_for(&video_nr, &caps, nr).map(|v| v == "Y" || v == "1");
        nodes.push(Node {
            nr,
            label,
            exclusive_caps,
        });
    }
    nodes.sort_by_key(|n| n.nr);
    nodes
}

const MODPROBE_FIX: &str = "put `options v4l2loopback devices=1 video_nr=42 card_label=\"SDI camera\" exclusive_caps=1 max_buffers=10` in /etc/modprobe.d/sdi.conf (`make install` does), stop sdid and every reader, then: sudo modprobe -r v4l2loopback && sudo modprobe v4l2loopback";

/// The nodes verdict (pure, unit-tested).
fn nodes_verdict(
    loaded: bool,
    nodes: &[Node],
    labels: &[&str],
    max_buffers: Option<u32>,
) -> Vec<Check> {
    if !loaded {
        return vec![Check::new("nodes", Status::Skip, "v4l2loopback not loaded")];
    }
    let mut out = Vec::new();
    for (k, label) in labels.iter().enumerate() {
        let id = if k == 0 { "view-node" } else { "data-node" };
        let Some(node) = nodes.iter().find(|n| n.label == *label) else {
            let have: Vec<String> = nodes
                .iter()
                .map(|n| format!("/dev/video{} \"{}\"", n.nr, n.label))
                .collect();
            out.push(
                Check::new(
                    id,
                    Status::Fail,
                    format!(
                        "no v4l2loopback node labelled \"{label}\" (have: {})",
                        if have.is_empty() {
                            "none".into()
                        } else {
                            have.join(", ")
                        }
                    ),
                )
                .fix(MODPROBE_FIX),
            );
            continue;
        };
        let dev = format!("/dev/video{} \"{label}\"", node.nr);
        match node.exclusive_caps {
            Some(false) => out.push(
                Check::new(id, Status::Fail, format!("{dev} has exclusive_caps=0: Chromium and Firefox do not list it (it offers OUTPUT as well as CAPTURE)"))
                    .fix(MODPROBE_FIX),
            ),
            None => out.push(Check::new(id, Status::Warn, format!("{dev}: exclusive_caps unknown (created at run time?); browsers need exclusive_caps=1"))),
            Some(true) => {}
        }
        match max_buffers {
            Some(b) if b < 3 => out.push(
                Check::new(id, Status::Fail, format!("{dev}: max_buffers={b}: PipeWire refuses fewer than 3 buffers and readers see torn frames"))
                    .fix(MODPROBE_FIX),
            ),
            Some(b) if b < 10 => out.push(Check::new(id, Status::Warn, format!("{dev}: max_buffers={b}; 10 gives slow readers room (docs/loopback.md)")).fix(MODPROBE_FIX)),
            _ => {}
        }
        if !out.iter().any(|c| c.id == id) {
            out.push(Check::new(
                id,
                Status::Ok,
                format!(
                    "{dev}, exclusive_caps=1, max_buffers={}",
                    max_buffers.map_or("?".into(), |b| b.to_string())
                ),
            ));
        }
    }
    out
}

/// Groups of this process, and of the user in the group database.
struct Groups {
    user: String,
    uid: u32,
    process: Vec<String>,
    database: Vec<String>,
    existing: Vec<String>,
}

fn groups(sys: &Sys) -> Groups {
    let uid = nix::unistd::getuid().as_raw();
    let user = nix::unistd::User::from_uid(nix::unistd::getuid())
        .ok()
        .flatten()
        .map_or_else(|| uid.to_string(), |u| u.name);
    let process: Vec<String> = nix::unistd::getgroups()
        .unwrap_or_default()
        .into_iter()
        .chain([nix::unistd::getegid()])
        .filter_map(|g| {
            nix::unistd::Group::from_gid(g)
                .ok()
                .flatten()
                .map(|g| g.name)
        })
        .collect();
    let database = output("id", &["-Gn", &user], Duration::from_secs(5))
        .map(|s| s.split_whitespace().map(str::to_owned).collect())
        .unwrap_or_default();
    let existing = sys
        .read("/etc/group")
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.split(':').next().map(str::to_owned))
        .collect();
    Groups {
        user,
        uid,
        process,
        database,
        existing,
    }
}

/// The groups verdict (pure, unit-tested).
fn groups_verdict(g: &Groups) -> Vec<Check> {
    let mut out = Vec::new();
    for (group, why) in [
        ("sdi", "controls sdid over D-Bus (sdictl)"),
        (
            "video",
            "opens /dev/video* outside a desktop session (ssh, services)",
        ),
    ] {
        let id = if group == "sdi" {
            "group-sdi"
        } else {
            "group-video"
        };
        let c = if g.uid == 0 {
            Check::new(id, Status::Ok, format!("root: no group {group} needed"))
        } else if g.process.iter().any(|p| p == group) {
            Check::new(id, Status::Ok, format!("{} is in group {group}", g.user))
        } else if !g.existing.iter().any(|e| e == group) {
            Check::new(id, Status::Fail, format!("group {group} does not exist"))
                .fix(if group == "sdi" { "install sdid: sudo make install (systemd-sysusers creates group sdi from udev/sysusers.d)" } else { "sudo groupadd --system video" })
        } else if g.database.iter().any(|p| p == group) {
            Check::new(
                id,
                Status::Fail,
                format!(
                    "{} was added to group {group}, but this session started before",
                    g.user
                ),
            )
            .fix("log out and back in (or reboot); `newgrp` works for one shell")
        } else {
            Check::new(
                id,
                Status::Fail,
                format!("{} is not in group {group}, which {why}", g.user),
            )
            .fix(format!(
                "sudo usermod -aG {group} {}, then log out and back in",
                g.user
            ))
        };
        out.push(c);
    }
    out
}

/// Which bus the daemon answered on (first that does), and its properties.
async fn daemon(bus: &BusArgs) -> (Check, Option<sdi_api::Properties>) {
    let mut tries: Vec<(String, BusArgs)> = Vec::new();
    if let Some(a) = &bus.bus_address {
        tries.push((format!("the bus at {a}"), bus.clone()));
    } else if bus.session {
        tries.push(("the session bus".into(), bus.clone()));
    } else {
        tries.push((
            "the system bus".into(),
            BusArgs {
                session: false,
                ..bus.clone()
            },
        ));
        tries.push((
            "the session bus".into(),
            BusArgs {
                session: true,
                ..bus.clone()
            },
        ));
    }
    let mut errors = Vec::new();
    for (name, args) in tries {
        let props = async {
            let cam = super::connect(&args).await?;
            Ok::<_, crate::exit::CliError>(sdi_api::Properties::read(&cam).await?)
        };
        match tokio::time::timeout(Duration::from_secs(10), props).await {
            Ok(Ok(p)) => {
                let (device, backend) = (&p.device, &p.backend);
                return (
                    Check::new(
                        "daemon",
                        Status::Ok,
                        format!("sdid answers on {name}: backend {backend}, {device}"),
                    ),
                    Some(p),
                );
            }
            Ok(Err(e)) => errors.push(format!("{name}: {e}")),
            Err(_) => errors.push(format!("{name}: no answer in 10 s")),
        }
    }
    (
        Check::new("daemon", Status::Fail, format!("sdid is not reachable ({})", errors.join("; ")))
            .fix("sudo systemctl enable --now sdid (see `journalctl -u sdid` if it does not stay up); for a per-user daemon: sdid --session, then sdictl --session ..."),
        None,
    )
}

/// USB boards of `udev/board-ids` in sysfs: (mode, speed in Mb/s, sysfs name).
fn boards(sys: &Sys) -> Vec<(&'static str, String, String)> {
    let ids = sdi_api::board_ids::board_ids();
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(sys.path("/sys/bus/usb/devices")) else {
        return out;
    };
    for e in entries.flatten() {
        let hex = |f: &str| {
            std::fs::read_to_string(e.path().join(f))
                .ok()
                .and_then(|s| u16::from_str_radix(s.trim(), 16).ok())
        };
        let (Some(v), Some(p)) = (hex("idVendor"), hex("idProduct")) else {
            continue;
        };
        if let Some((_, _, mode)) = ids.iter().find(|(iv, ip, _)| *iv == v && *ip == p) {
            let speed = std::fs::read_to_string(e.path().join("speed"))
                .map(|s| s.trim().to_owned())
                .unwrap_or_default();
            out.push((*mode, speed, e.file_name().to_string_lossy().into_owned()));
        }
    }
    out
}

/// The board verdict (pure, unit-tested).
fn board_verdict(found: &[(&str, String, String)]) -> Check {
    let Some((mode, speed, name)) = found.first() else {
        return Check::new("board", Status::Warn, "no OPT8241-CDK attached (USB IDs of udev/board-ids): sdid shows the simulator or the no-signal card")
            .fix("plug the board in (a USB 2.0 port or better); `lsusb -d 0451:` should list 0451:9105 or 0451:9106");
    };
    let speed_text = match speed.as_str() {
        "1.5" | "12" => format!("{speed} Mb/s (USB 1.x: too slow for frames)"),
        "480" => "480 Mb/s (high speed)".into(),
        s => format!("{s} Mb/s"),
    };
    let slow = matches!(speed.as_str(), "1.5" | "12");
    let mut c = match *mode {
        "bulk" => Check::new("board", Status::Ok, format!("OPT8241-CDK at usb {name}, bulk mode, {speed_text}")),
        m => Check::new("board", Status::Ok, format!("OPT8241-CDK at usb {name}, {m} mode (sdid switches it to bulk mode when it opens it), {speed_text}")),
    };
    if slow {
        c.status = Status::Warn;
        c.fix = Some("use a USB 2.0 (or faster) port and cable, without a USB 1.1 hub".into());
    }
    c
}

/// Runs every check; exit status 0 only when none fails.
fn print_checks(checks: &[Check], ok: bool, json: bool) -> Result<(), crate::stdout::StdoutError> {
    if json {
        let list: Vec<Json> = checks.iter().map(Check::json).collect();
        outln!("{}", json!({ "ok": ok, "checks": list }))?;
    } else {
        for c in checks {
            outln!("[{:>4}] {:<12} {}", c.status.tag(), c.id, c.summary)?;
            if let (Some(fix), Status::Fail | Status::Warn) = (&c.fix, c.status) {
                outln!("       {:<12} fix: {fix}", "")?;
            }
        }
        let fails = checks.iter().filter(|c| c.status == Status::Fail).count();
        outln!(
            "{}",
            if ok {
                "nothing blocks the SDI camera".to_owned()
            } else {
                format!("{fails} problem(s) block the SDI camera")
            }
        )?;
    }
    Ok(())
}

pub fn run(bus: &BusArgs, sysroot: &Path) -> ExitCode {
    let sys = Sys {
        root: sysroot.to_owned(),
    };
    let config = sdi_config::Config::load(None)
        .map(|(c, _)| c)
        .unwrap_or_default();
    let mut labels = vec![config.output.label.clone()];
    if !config.output.data_label.is_empty() {
        labels.push(config.output.data_label.clone());
    }
    let labels: Vec<&str> = labels.iter().map(String::as_str).collect();

    let m = module(&sys);
    let mut checks = vec![check_module(&m)];
    checks.push(signature_verdict(
        secure_boot(&sys),
        lockdown(&sys).as_deref(),
        &m,
    ));
    let max_buffers = sys
        .read("/sys/module/v4l2loopback/parameters/max_buffers")
        .and_then(|s| s.parse().ok());
    checks.extend(nodes_verdict(
        m.loaded,
        &loopback_nodes(&sys),
        &labels,
        max_buffers,
    ));
    checks.extend(groups_verdict(&groups(&sys)));
    let daemon = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt.block_on(daemon(bus)).0,
        Err(e) => Check::new("daemon", Status::Fail, format!("no async runtime: {e}")),
    };
    checks.push(daemon);
    checks.push(board_verdict(&boards(&sys)));
    checks.push(pipewire::camera());
    checks.extend(pipewire::checks(&labels));

    let ok = !checks.iter().any(|c| c.status == Status::Fail);
    // A closed stdout still leaves the verdict in the exit status; any
    // other failure to print is an error (stdout.rs).
    if let Err(crate::stdout::StdoutError::Failed(e)) = print_checks(&checks, ok, bus.json) {
        let _ = writeln!(std::io::stderr(), "error: cannot write to stdout: {e}");
        return ExitCode::from(1);
    }
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn module(installed: bool, loaded: bool, signer: Option<&str>, taint: Option<&str>) -> Module {
        Module {
            installed,
            loaded,
            version: None,
            signer: signer.map(str::to_owned),
            taint: taint.map(str::to_owned),
        }
    }

    #[test]
    fn unsigned_module_under_secure_boot_fails_with_mok_steps() {
        let c = signature_verdict(
            Some(true),
            Some("integrity"),
            &module(true, false, None, None),
        );
        assert_eq!(c.status, Status::Fail);
        assert!(c
            .fix
            .as_deref()
            .is_some_and(|f| f.contains("mokutil --import") && f.contains("Key was rejected")));
        let c = signature_verdict(
            Some(true),
            None,
            &module(true, false, Some("DKMS module signing key"), None),
        );
        assert_eq!(c.status, Status::Warn);
        let c = signature_verdict(Some(false), Some("none"), &module(true, false, None, None));
        assert_eq!(c.status, Status::Ok);
        // lockdown alone (no Secure Boot) also refuses unsigned modules
        let c = signature_verdict(None, Some("integrity"), &module(true, false, None, None));
        assert_eq!(c.status, Status::Fail);
        // loaded: it got in, whatever the state
        let c = signature_verdict(Some(true), None, &module(true, true, None, Some("OE")));
        assert_eq!(c.status, Status::Ok);
        assert!(c.summary.contains("unsigned"));
        let c = signature_verdict(None, None, &module(false, false, None, None));
        assert_eq!(c.status, Status::Skip);
    }

    #[test]
    fn per_node_parameters_follow_video_nr() {
        assert_eq!(param_for("42,43,-1", "Y,N,N", 43).as_deref(), Some("N"));
        assert_eq!(param_for("42,43,-1", "Y,N,N", 42).as_deref(), Some("Y"));
        assert_eq!(param_for("42,-1", "Y,N", 7), None);
    }

    #[test]
    fn nodes_need_exclusive_caps_and_three_buffers() {
        let node = |caps| Node {
            nr: 42,
            label: "SDI camera".into(),
            exclusive_caps: caps,
        };
        let ok = nodes_verdict(true, &[node(Some(true))], &["SDI camera"], Some(10));
        assert_eq!(ok.len(), 1);
        assert_eq!(ok[0].status, Status::Ok);
        let bad = nodes_verdict(true, &[node(Some(false))], &["SDI camera"], Some(2));
        assert_eq!(bad.len(), 2);
        assert!(bad
            .iter()
            .all(|c| c.status == Status::Fail && c.fix.is_some()));
        let missing = nodes_verdict(
            true,
            &[node(Some(true))],
            &["SDI camera", "SDI data"],
            Some(10),
        );
        assert_eq!(missing[1].status, Status::Fail);
        assert_eq!(missing[1].id, "data-node");
        assert_eq!(
            nodes_verdict(false, &[], &["SDI camera"], None)[0].status,
            Status::Skip
        );
    }

    #[test]
    fn groups_tell_relogin_from_missing() {
        let g = |process: &[&str], database: &[&str]| Groups {
            user: "ann".into(),
            uid: 1000,
            process: process.iter().map(|s| (*s).to_owned()).collect(),
            database: database.iter().map(|s| (*s).to_owned()).collect(),
            existing: vec!["sdi".into(), "video".into()],
        };
        let v = groups_verdict(&g(&["sdi", "video"], &["sdi", "video"]));
        assert!(v.iter().all(|c| c.status == Status::Ok));
        let v = groups_verdict(&g(&["video"], &["sdi", "video"]));
        assert_eq!(v[0].status, Status::Fail);
        assert!(v[0].fix.as_deref().is_some_and(|f| f.contains("log out")));
        let v = groups_verdict(&g(&[], &[]));
        assert!(v[1]
            .fix
            .as_deref()
            .is_some_and(|f| f.contains("usermod -aG video ann")));
    }

    #[test]
    fn board_modes_and_speeds() {
        assert_eq!(board_verdict(&[]).status, Status::Warn);
        let c = board_verdict(&[("uvc", "480".into(), "1-1".into())]);
        assert_eq!(c.status, Status::Ok);
        assert!(c.summary.contains("uvc mode"));
        assert_eq!(
            board_verdict(&[("bulk", "12".into(), "1-1".into())]).status,
            Status::Warn
        );
    }
}
