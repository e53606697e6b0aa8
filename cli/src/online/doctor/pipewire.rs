//! The doctor's PipeWire checks: the camera program, and which SDI nodes
//! this user's PipeWire lists (`pw-dump`, run as the caller), whether each
//! can be read, and the fix.
//!
//! Whether a node can be read is judged from what `pw-dump` shows, not by
//! streaming from it: a node in state "error" cannot, and a v4l2loopback
//! node cannot before PipeWire 1.3.81 (no VIDIOC_EXPBUF, docs/loopback.md),
//! whatever its state says until a reader links.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value as Json;

use super::{output, Check, Status};
use sdi_camera_link::is_camera_node;

/// The first PipeWire that reads a v4l2loopback node (docs/loopback.md).
const READS_LOOPBACK: (u32, u32, u32) = (1, 3, 81);

/// What to do about a loopback node PipeWire lists but cannot read.
const RULE_FIX: &str = "install sdi-pipewire-camera: sdid then feeds the PipeWire camera (node \"sdi-camera\") beside the loopback nodes, and its WirePlumber rule (/usr/share/wireplumber/main.lua.d/51-sdi-v4l2.lua; wireplumber.conf.d/51-sdi-v4l2.conf on WirePlumber 0.5) keeps the loopback nodes out of PipeWire; then: systemctl --user restart wireplumber";

/// A PipeWire version ("0.3.65") as numbers.
fn version(text: &str) -> Option<(u32, u32, u32)> {
    let mut parts = text.split('.').map(|p| p.parse::<u32>().ok());
    Some((parts.next()??, parts.next()??, parts.next()??))
}

/// One SDI node as PipeWire lists it.
struct SdiNode {
    name: String,
    role: Option<String>,
    state: String,
    error: Option<String>,
    /// A v4l2 node of SDI's loopback device (else the camera process's).
    loopback: bool,
}

fn str_of<'a>(p: &'a Json, key: &str) -> Option<&'a str> {
    p.get(key).and_then(Json::as_str)
}

/// The SDI nodes in `pw-dump`'s objects: the camera processes' by node
/// name (every camera's), the loopback device's by card label.
fn sdi_nodes(objects: &[Json], labels: &[&str]) -> Vec<SdiNode> {
    objects
        .iter()
        .filter(|o| o["type"] == "PipeWire:Interface:Node")
        .filter_map(|o| {
            let p = &o["info"]["props"];
            let name = str_of(p, "node.name").unwrap_or_default();
            let camera = is_camera_node(name);
            let loopback = ["api.v4l2.cap.card", "device.product.name"]
                .iter()
                .any(|k| str_of(p, k).is_some_and(|c| is_sdi_label(c, labels)));
            (camera || loopback).then(|| SdiNode {
                name: str_of(p, "node.description").unwrap_or(name).to_owned(),
                role: str_of(p, "media.role").map(str::to_owned),
                state: o["info"]["state"].as_str().unwrap_or("unknown").to_owned(),
                error: o["info"]["error"].as_str().map(str::to_owned),
                loopback: !camera,
            })
        })
        .collect()
}

/// Whether a card label is one of `labels`, alone or followed by a
/// camera's serial (several cameras: "SDI camera sim-1", camera_plan.rs).
fn is_sdi_label(card: &str, labels: &[&str]) -> bool {
    labels.iter().any(|l| {
        card.strip_prefix(l)
            .is_some_and(|rest| rest.is_empty() || rest.starts_with(' '))
    })
}

/// The verdict on one node: readable or not, and why.
fn node_check(n: &SdiNode, pipewire: &str, reads_loopback: bool) -> Check {
    let what = format!(
        "PipeWire lists \"{}\" ({}, media.role {}, state {})",
        n.name,
        if n.loopback {
            "v4l2loopback node"
        } else {
            "the PipeWire camera"
        },
        n.role.as_deref().unwrap_or("none"),
        n.state
    );
    if n.state == "error" {
        let why = n.error.as_deref().unwrap_or("no reason given");
        let fix = match n.loopback {
            true => RULE_FIX,
            false => "restart sdid (it starts the camera process again)",
        };
        return Check::new(
            "pw-node",
            Status::Warn,
            format!("{what}: cannot be read ({why})"),
        )
        .fix(fix);
    }
    match (n.loopback, reads_loopback) {
        (false, _) => Check::new("pw-node", Status::Ok, format!("{what}: readable")),
        (true, true) => Check::new(
            "pw-node",
            Status::Ok,
            format!("{what}: readable (PipeWire {pipewire} reads v4l2loopback)"),
        ),
        (true, false) => Check::new(
            "pw-node",
            Status::Warn,
            format!(
                "{what}: cannot be read: PipeWire {pipewire} cannot read a v4l2loopback node (no VIDIOC_EXPBUF; PipeWire reads it from 1.3.81), so portal clients (browsers, Flatpak apps, OBS) that pick it get no frame; V4L2 clients are not affected"
            ),
        )
        .fix(RULE_FIX),
    }
}

/// PipeWire's view of SDI (pure over `pw-dump`'s JSON, unit-tested): a
/// summary line, then one line per SDI node.
fn verdict(dump: Option<&str>, installed: bool, labels: &[&str]) -> Vec<Check> {
    if !installed {
        return vec![Check::new(
            "pipewire",
            Status::Skip,
            "PipeWire is not installed (pw-dump not found)",
        )];
    }
    let Some(dump) = dump else {
        return vec![Check::new("pipewire", Status::Warn, "PipeWire is not running for this user (pw-dump failed): apps that use the camera portal (Flatpak, GNOME) will not see the camera")
            .fix("systemctl --user enable --now pipewire wireplumber")];
    };
    let objects: Vec<Json> = serde_json::from_str(dump).unwrap_or_default();
    let pipewire = objects
        .iter()
        .find(|o| o["type"] == "PipeWire:Interface:Core")
        .and_then(|o| o["info"]["version"].as_str())
        .unwrap_or("(version unknown)")
        .to_owned();
    let reads_loopback = version(&pipewire).is_some_and(|v| v >= READS_LOOPBACK);
    let nodes = sdi_nodes(&objects, labels);
    let checks: Vec<Check> = nodes
        .iter()
        .map(|n| node_check(n, &pipewire, reads_loopback))
        .collect();
    let cameras: Vec<&SdiNode> = nodes
        .iter()
        .filter(|n| n.role.as_deref() == Some("Camera"))
        .collect();
    let readable = nodes
        .iter()
        .zip(&checks)
        .filter(|(n, c)| n.role.as_deref() == Some("Camera") && c.status == Status::Ok)
        .count();
    // Several cameras' own nodes (sdi-camera-SERIAL) are no duplicate.
    let each_its_own = cameras.iter().all(|c| !c.loopback);
    let summary = match (cameras.len(), readable) {
        (0, _) => Check::new(
            "pipewire",
            Status::Warn,
            format!("PipeWire {pipewire} runs but lists no SDI camera: no sdid feeds the PipeWire camera for this user, or WirePlumber probed the loopback node while it was not a capture device (exclusive_caps=1, sdid not streaming yet) and probes again only on a udev event"),
        )
        .fix("run sdid in this session (systemctl --user start sdid) or, with the system service, start the camera for this user (systemctl --user start sdi-pipewire-camera); for the loopback node once sdid streams: sudo udevadm trigger --action=change --subsystem-match=video4linux"),
        (1, 1) => Check::new(
            "pipewire",
            Status::Ok,
            format!("PipeWire {pipewire} lists one SDI camera, and it can be read"),
        ),
        (n, r) if each_its_own && r == n => Check::new(
            "pipewire",
            Status::Ok,
            format!(
                "PipeWire {pipewire} lists {n} SDI cameras ({}), one per camera, each readable",
                cameras
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ),
        (n, 0) => Check::new(
            "pipewire",
            Status::Warn,
            format!("PipeWire {pipewire} lists {n} SDI camera(s), none readable"),
        )
        .fix(RULE_FIX),
        (n, _) => Check::new(
            "pipewire",
            Status::Warn,
            format!("PipeWire {pipewire} lists {n} SDI cameras ({}): pickers show \"SDI camera\" more than once", cameras.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")),
        )
        .fix(RULE_FIX),
    };
    std::iter::once(summary).chain(checks).collect()
}

/// This user's PipeWire as `pw-dump` shows it.
pub(super) fn checks(labels: &[&str]) -> Vec<Check> {
    let installed = output("pw-dump", &["--version"], Duration::from_secs(5)).is_some();
    let dump = if installed {
        output("pw-dump", &[], Duration::from_secs(10))
    } else {
        None
    };
    verdict(dump.as_deref(), installed, labels)
}

/// The PipeWire camera program, where sdid looks for it (pure over the
/// candidates and which of them exist, unit-tested).
fn camera_verdict(candidates: &[PathBuf], exists: impl Fn(&Path) -> bool) -> Check {
    let program = sdi_camera_link::CAMERA_PROGRAM;
    match candidates.iter().find(|p| exists(p)) {
        Some(p) => Check::new(
            "pipewire-camera",
            Status::Ok,
            format!("{program} installed: {}", p.display()),
        ),
        None => Check::new(
            "pipewire-camera",
            Status::Warn,
            format!(
                "the PipeWire camera ({program}) is not installed beside sdid (looked for {}): \
                 PipeWire apps see no readable \"SDI camera\" (without v4l2loopback sdid streams y4m; \
                 with it, PipeWire before 1.3.81 cannot read the loopback node)",
                candidates
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
        .fix(format!(
            "sudo apt install ./sdi-pipewire-camera_*.deb (make deb builds it), or from a checkout: \
             cargo build --release -p sdi-pipewire-camera, which needs {}",
            sdi_camera_link::CAMERA_BUILD_PACKAGES
        )),
    }
}

/// [`camera_verdict`] for the sdid beside this sdictl.
pub(super) fn camera() -> Check {
    let dir = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
        .unwrap_or_default();
    camera_verdict(&sdi_camera_link::camera_candidates(&dir), |p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_camera_link::{DATA_NODE, VIEW_NODE};

    const LABELS: &[&str] = &["SDI camera", "SDI data"];

    fn dump(version: &str, nodes: &[(&str, &str, Option<&str>, &str)]) -> String {
        let mut objects = vec![serde_json::json!({
            "id": 0, "type": "PipeWire:Interface:Core",
            "info": { "version": version, "props": {} }
        })];
        for (i, (name, card, role, state)) in nodes.iter().enumerate() {
            let mut props = serde_json::json!({
                "node.name": name, "media.class": "Video/Source",
                "node.description": format!("{name} description"),
            });
            if !card.is_empty() {
                props["api.v4l2.cap.card"] = (*card).into();
            }
            if let Some(r) = role {
                props["media.role"] = (*r).into();
            }
            objects.push(serde_json::json!({
                "id": 50 + i, "type": "PipeWire:Interface:Node",
                "info": { "state": state, "props": props }
            }));
        }
        Json::Array(objects).to_string()
    }

    fn statuses(c: &[Check]) -> Vec<(&'static str, Status)> {
        c.iter().map(|c| (c.id, c.status)).collect()
    }

    #[test]
    fn the_camera_process_alone_is_one_readable_camera() {
        let d = dump(
            "0.3.65",
            &[
                (VIEW_NODE, "", Some("Camera"), "suspended"),
                (DATA_NODE, "", None, "suspended"),
                ("alsa_output.x", "", None, "idle"),
            ],
        );
        let c = verdict(Some(&d), true, LABELS);
        assert_eq!(
            statuses(&c),
            [
                ("pipewire", Status::Ok),
                ("pw-node", Status::Ok),
                ("pw-node", Status::Ok)
            ]
        );
        assert!(c[0].summary.contains("0.3.65"), "{}", c[0].summary);
    }

    #[test]
    fn a_loopback_node_before_1_3_81_cannot_be_read_and_the_fix_is_the_rule() {
        let d = dump(
            "0.3.65",
            &[(
                "v4l2_input.platform-v4l2loopback-000",
                "SDI camera",
                Some("Camera"),
                "suspended",
            )],
        );
        let c = verdict(Some(&d), true, LABELS);
        assert_eq!(
            statuses(&c),
            [("pipewire", Status::Warn), ("pw-node", Status::Warn)]
        );
        assert!(c[1].summary.contains("cannot be read"), "{}", c[1].summary);
        assert!(c[1]
            .fix
            .as_deref()
            .unwrap_or_default()
            .contains("51-sdi-v4l2"));
        // From 1.3.81 the same node reads.
        let d = d.replace("0.3.65", "1.4.2");
        let c = verdict(Some(&d), true, LABELS);
        assert_eq!(
            statuses(&c),
            [("pipewire", Status::Ok), ("pw-node", Status::Ok)]
        );
    }

    #[test]
    fn two_sdi_cameras_are_one_too_many() {
        let d = dump(
            "1.4.2",
            &[
                (VIEW_NODE, "", Some("Camera"), "running"),
                ("v4l2_input.x", "SDI camera", Some("Camera"), "suspended"),
            ],
        );
        let c = verdict(Some(&d), true, LABELS);
        assert_eq!(c[0].status, Status::Warn);
        assert!(c[0].summary.contains("2 SDI cameras"), "{}", c[0].summary);
    }

    #[test]
    fn each_of_several_cameras_own_node_is_no_duplicate() {
        let d = dump(
            "0.3.65",
            &[
                ("sdi-camera-sim-0", "", Some("Camera"), "running"),
                ("sdi-camera-sim-1", "", Some("Camera"), "idle"),
                ("sdi-camera-data-sim-1", "", None, "idle"),
            ],
        );
        let c = verdict(Some(&d), true, LABELS);
        assert_eq!(c[0].status, Status::Ok, "{}", c[0].summary);
        assert!(c[0].summary.contains("2 SDI cameras"), "{}", c[0].summary);
        assert_eq!(c.len(), 4);
        // A camera's loopback node beside them is one too many.
        let d = dump(
            "0.3.65",
            &[
                ("sdi-camera-sim-0", "", Some("Camera"), "running"),
                (
                    "v4l2_input.x",
                    "SDI camera sim-0",
                    Some("Camera"),
                    "suspended",
                ),
            ],
        );
        assert_eq!(verdict(Some(&d), true, LABELS)[0].status, Status::Warn);
        assert!(is_sdi_label("SDI data A1", LABELS));
        assert!(!is_sdi_label("SDI cameraX", LABELS));
    }

    #[test]
    fn a_node_in_error_cannot_be_read() {
        let d = dump("0.3.65", &[(VIEW_NODE, "", Some("Camera"), "error")]);
        let c = verdict(Some(&d), true, LABELS);
        assert_eq!(
            statuses(&c),
            [("pipewire", Status::Warn), ("pw-node", Status::Warn)]
        );
    }

    #[test]
    fn no_pipewire_or_no_sdi_camera_says_why() {
        assert_eq!(verdict(Some("[]"), true, LABELS)[0].status, Status::Warn);
        assert_eq!(verdict(None, true, LABELS)[0].status, Status::Warn);
        assert_eq!(verdict(None, false, LABELS)[0].status, Status::Skip);
        assert_eq!(version("1.3.81"), Some((1, 3, 81)));
        assert_eq!(version("0.3"), None);
    }

    #[test]
    fn a_missing_pipewire_camera_names_its_package() {
        let c = sdi_camera_link::camera_candidates(Path::new("/usr/bin"));
        let missing = camera_verdict(&c, |_| false);
        assert_eq!(missing.status, Status::Warn);
        let fix = missing.fix.as_deref().unwrap_or_default();
        assert!(fix.contains("sdi-pipewire-camera"), "{fix}");
        assert!(fix.contains("libpipewire-0.3-dev"), "{fix}");
        assert!(missing.summary.contains("/usr/bin/sdi-pipewire-camera"));
        let packaged = camera_verdict(&c, |p| p.starts_with("/usr/bin/../libexec"));
        assert_eq!(packaged.status, Status::Ok);
        assert!(packaged.summary.contains("libexec/sdi/sdi-pipewire-camera"));
    }
}
