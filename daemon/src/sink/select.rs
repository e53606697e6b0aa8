//! The output sinks the validated configuration asks for (`auto`:
//! v4l2loopback, and beside it the PipeWire camera where this user's
//! PipeWire runs; else PipeWire; else the y4m stream), and for `auto` why.
//! Each of several cameras has its own PipeWire camera, named by its
//! serial ([`sdi_camera_link::Names`]).

use std::path::PathBuf;

use v4l2loopback_glue::GlueError;

use super::loopback::LoopbackSink;
use super::pipewire::{PipewireSink, VIEW_NODE};
use super::pipewire_launch;
use super::system_feed::{self, SystemFeed};
use super::y4m::Y4mSink;
use super::{Sink, SinkError, SinkKindName, SinkSet};
use sdi_camera_link::Spec;
use sdi_config::{Config, SinkKind};
use sdi_core::mode::ModeId;

/// The chosen sinks and, for `auto`, why: each sink passed over in a phrase
/// that names what to install (the full errors are at debug level), and
/// what made the chosen ones fit.
pub struct Chosen {
    pub sinks: SinkSet,
    pub reasons: Option<Vec<String>>,
}

impl Chosen {
    /// The reasons in one phrase ("...; ..."), when `auto` chose.
    pub fn reasons(&self) -> Option<String> {
        self.reasons.as_ref().map(|p| p.join("; "))
    }
}

/// Why `auto` passed over the loopback sink, for people.
fn loopback_phrase(e: &SinkError, label: &str) -> String {
    match e {
        SinkError::Loopback(GlueError::ModuleNotLoaded { .. }) => {
            "no v4l2loopback module loaded (package v4l2loopback-dkms)".into()
        }
        SinkError::Loopback(GlueError::DeviceNotFound { not_added, .. }) => match not_added {
            Some(why) => format!("no v4l2loopback device labelled \"{label}\" (not added: {why})"),
            None => format!("no v4l2loopback device labelled \"{label}\""),
        },
        e => format!("v4l2loopback unusable: {e}"),
    }
}

/// Why `auto` passed over the PipeWire sink, for people.
fn pipewire_phrase(e: &SinkError) -> String {
    match e {
        SinkError::CameraNotInstalled(_) => {
            "the PipeWire camera is not installed (package sdi-pipewire-camera)".into()
        }
        e => format!("PipeWire unusable: {e}"),
    }
}

fn open_pipewire(spec: &Spec) -> Result<Box<dyn Sink>, SinkError> {
    let program = pipewire_launch::find_program()?;
    let s = PipewireSink::open(&program, spec.clone())?;
    Ok(Box::new(s))
}

/// Why the PipeWire camera cannot carry this camera, if it cannot: one of
/// several cameras without a serial that names its nodes (the lone
/// camera's names are another's).
fn pipewire_refused(c: &Config, spec: &Spec) -> Option<&'static str> {
    (c.cameras > 1 && spec.camera.is_none())
        .then_some("this camera's serial cannot name its PipeWire nodes")
}

/// Opens the output sink of a camera: `serial` names its PipeWire camera
/// when it is one of several (and [names a file](sdi_core::serial::names_a_file)).
pub fn open(
    c: &Config,
    width: usize,
    height: usize,
    fps: f64,
    mode: ModeId,
    serial: Option<&str>,
) -> Result<Chosen, SinkError> {
    let camera = serial.filter(|s| c.cameras > 1 && sdi_core::serial::names_a_file(s));
    let spec = PipewireSink::spec(width, height, fps, mode, camera);
    let refused = pipewire_refused(c, &spec);
    let kind = c.output.sink;
    let auto = kind == SinkKind::Auto;
    let mut passed = Vec::new();
    if auto || kind == SinkKind::Loopback {
        match LoopbackSink::open(&c.output.label, &c.output.data_label, width, height, fps) {
            Ok(s) => {
                passed.push(format!(
                    "v4l2loopback device labelled \"{}\" found",
                    c.output.label
                ));
                let also = match (auto, refused) {
                    (true, None) => beside_loopback(&spec, &mut passed),
                    _ => Vec::new(),
                };
                return Ok(Chosen {
                    sinks: SinkSet {
                        primary: Box::new(s),
                        also,
                    },
                    reasons: auto.then_some(passed),
                });
            }
            Err(e) if !auto => return Err(e),
            Err(e) => {
                tracing::debug!("auto: v4l2loopback passed over: {e}");
                passed.push(loopback_phrase(&e, &c.output.label));
            }
        }
    }
    let wants_pipewire = auto || kind == SinkKind::Pipewire;
    if let (true, Some(why)) = (wants_pipewire, refused) {
        if !auto {
            return Err(SinkError::PipewireRefused(why));
        }
        passed.push(why.into());
    } else if auto && pipewire_launch::pipewire_socket().is_none() {
        passed.push("no PipeWire running for this user".into());
    } else if wants_pipewire {
        match open_pipewire(&spec) {
            Ok(sink) => {
                passed.push("PipeWire reachable".into());
                return Ok(Chosen {
                    sinks: SinkSet {
                        primary: sink,
                        also: Vec::new(),
                    },
                    reasons: auto.then_some(passed),
                });
            }
            Err(e) if !auto => return Err(e),
            Err(e) => {
                tracing::debug!("auto: PipeWire passed over: {e}");
                passed.push(pipewire_phrase(&e));
            }
        }
    }
    let path = (!c.output.y4m_path.is_empty()).then(|| PathBuf::from(&c.output.y4m_path));
    let sink = Y4mSink::new(path.as_deref(), width, height, fps).map_err(SinkError::Y4m)?;
    let also = match (auto, refused, system_feed::runtime_directory()) {
        (true, None, Some(dir)) => feed_users(&dir, &spec, &mut passed),
        _ => Vec::new(),
    };
    Ok(Chosen {
        sinks: SinkSet {
            primary: Box::new(sink),
            also,
        },
        reasons: auto.then_some(passed),
    })
}

/// The PipeWire camera fed beside the loopback nodes, where it is installed;
/// started once this user's PipeWire runs (a session's PipeWire may come up
/// after sdid). As the system service, the users' cameras connect to sdid
/// instead (`system_feed.rs`). PipeWire before 1.3.81 cannot read a v4l2loopback node
/// (no VIDIOC_EXPBUF, docs/loopback.md), so its portal clients get the
/// camera process's node instead (the loopback node is kept out of
/// PipeWire by SDI's WirePlumber rule, docs/pipewire.md).
fn beside_loopback(spec: &Spec, passed: &mut Vec<String>) -> Vec<Box<dyn Sink>> {
    if let Some(dir) = system_feed::runtime_directory() {
        return feed_users(&dir, spec, passed);
    }
    let opened = match pipewire_launch::pipewire_socket() {
        Some(_) => open_pipewire(spec).map(|s| (s, "PipeWire reachable")),
        None => pipewire_launch::find_program()
            .map_err(SinkError::from)
            .map(|program| {
                let s = PipewireSink::when_reachable(&program, spec.clone());
                let s: Box<dyn Sink> = Box::new(s);
                (s, "no PipeWire running for this user yet")
            }),
    };
    match opened {
        Ok((sink, why)) => {
            passed.push(format!("{why}: the PipeWire camera beside it"));
            vec![sink]
        }
        Err(e) => {
            tracing::debug!("auto: PipeWire camera beside v4l2loopback passed over: {e}");
            passed.push(pipewire_phrase(&e));
            Vec::new()
        }
    }
}

/// As the system service: the PipeWire cameras of users' sessions, which
/// connect to sdid's feed socket in `dir` (`system_feed.rs`).
fn feed_users(dir: &std::path::Path, spec: &Spec, passed: &mut Vec<String>) -> Vec<Box<dyn Sink>> {
    match SystemFeed::listen(dir, spec.clone()) {
        Ok(feed) => {
            passed.push(
                "system service: the PipeWire cameras of users' sessions are fed beside it".into(),
            );
            vec![Box::new(feed)]
        }
        Err(e) => {
            passed.push(format!("no PipeWire camera feed: {e}"));
            Vec::new()
        }
    }
}

/// What a person opens to watch the sink, and how: the lines of sdid's
/// first screen after the sink is chosen.
pub fn how_to_watch(kind: SinkKindName, device: &str) -> String {
    match kind {
        SinkKindName::Y4m if device == "stdout" => "sdid ... | ffplay -i -".into(),
        SinkKindName::Y4m => format!("ffplay {device}"),
        SinkKindName::Pipewire => {
            // The device names the view node first ("PipeWire node \"sdi-camera...\" ...").
            let node = device.split('"').nth(1).unwrap_or(VIEW_NODE);
            format!(
                "any PipeWire camera picker (\"SDI camera\"), or \
                 gst-launch-1.0 pipewiresrc target-object={node} ! videoconvert ! autovideosink"
            )
        }
        SinkKindName::Loopback => {
            format!("ffplay {device} (or any V4L2 camera application: \"SDI camera\")")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_of_several_cameras_has_its_pipewire_camera() {
        let mut c = Config::default();
        let spec = |camera: Option<&str>| PipewireSink::spec(320, 240, 30.0, ModeId::Raw, camera);
        assert_eq!(pipewire_refused(&c, &spec(None)), None);
        c.cameras = 2;
        assert_eq!(pipewire_refused(&c, &spec(Some("sim-1"))), None);
        // One of several without a serial that names its nodes.
        assert!(pipewire_refused(&c, &spec(None)).is_some());
    }

    #[test]
    fn how_to_watch_names_the_cameras_node() {
        let lone = how_to_watch(
            SinkKindName::Pipewire,
            "PipeWire node \"sdi-camera\" (YUYV)",
        );
        assert!(lone.contains("target-object=sdi-camera !"), "{lone}");
        let one = how_to_watch(
            SinkKindName::Pipewire,
            "PipeWire node \"sdi-camera-sim-1\" (YUYV)",
        );
        assert!(one.contains("target-object=sdi-camera-sim-1 !"), "{one}");
    }
}
