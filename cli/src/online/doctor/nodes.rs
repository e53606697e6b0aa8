//! The SDI nodes v4l2loopback made: present, `exclusive_caps`, enough buffers.

use super::{Check, Status, Sys};

/// A v4l2loopback node: number, label and its module parameters.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Node {
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

pub(super) fn loopback_nodes(sys: &Sys) -> Vec<Node> {
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
pub(super) fn nodes_verdict(
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
