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
//! check fails; warnings do not block. Each group of checks has its file:
//! `module.rs`, `nodes.rs`, `groups.rs`, `board.rs`, `pipewire.rs`.
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
use board::{board_verdict, boards};
use groups::{groups, groups_verdict};
use module::{check_module, lockdown, module, secure_boot, signature_verdict};
use nodes::{loopback_nodes, nodes_verdict};

mod board;
mod groups;
mod module;
mod nodes;
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

/// Which bus the daemon answered on (first that does), and a line per camera.
async fn daemon(bus: &BusArgs) -> Vec<Check> {
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
        let listed = async {
            let conn = super::connect_bus(&args).await?;
            Ok::<_, crate::exit::CliError>(sdi_api::cameras::list(&conn).await?)
        };
        match tokio::time::timeout(Duration::from_secs(10), listed).await {
            Ok(Ok(cameras)) => return camera_checks(&name, &cameras, bus.camera.as_deref()),
            Ok(Err(e)) => errors.push(format!("{name}: {e}")),
            Err(_) => errors.push(format!("{name}: no answer in 10 s")),
        }
    }
    vec![
        Check::new("daemon", Status::Fail, format!("sdid is not reachable ({})", errors.join("; ")))
            .fix("sudo systemctl enable --now sdid (see `journalctl -u sdid` if it does not stay up); for a per-user daemon: sdid --session, then sdictl --session ..."),
    ]
}

/// One line per camera sdid serves on `bus_name` (only `wanted`, if named).
fn camera_checks(
    bus_name: &str,
    cameras: &[sdi_api::cameras::Listed],
    wanted: Option<&str>,
) -> Vec<Check> {
    let chosen: Vec<_> = match wanted {
        Some(w) => match sdi_api::cameras::choose(cameras, Some(w)) {
            Ok(c) => vec![c],
            Err(e) => return vec![Check::new("daemon", Status::Fail, e.to_string())],
        },
        None => cameras.iter().collect(),
    };
    if chosen.is_empty() {
        return vec![Check::new(
            "daemon",
            Status::Fail,
            format!("sdid answers on {bus_name} but serves no camera"),
        )];
    }
    chosen
        .into_iter()
        .map(|c| {
            Check::new(
                "daemon",
                Status::Ok,
                format!(
                    "sdid answers on {bus_name}: camera {}, backend {}, {}",
                    c.serial, c.backend, c.device
                ),
            )
        })
        .collect()
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
        Ok(rt) => rt.block_on(daemon(bus)),
        Err(e) => vec![Check::new(
            "daemon",
            Status::Fail,
            format!("no async runtime: {e}"),
        )],
    };
    checks.extend(daemon);
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
