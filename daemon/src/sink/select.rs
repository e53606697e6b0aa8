//! The output sink the validated configuration asks for (`auto`:
//! v4l2loopback, else PipeWire, else the y4m stream).

use std::path::PathBuf;

use super::loopback::LoopbackSink;
use super::y4m::Y4mSink;
use super::Sink;
use crate::config::{Config, SinkKind};
use crate::modes::ModeId;

fn open_pipewire(
    width: usize,
    height: usize,
    fps: f64,
    mode: ModeId,
) -> Result<Box<dyn Sink>, String> {
    use super::pipewire::{PipewireSink, VIEW_NODE};
    let program = super::pipewire_launch::find_program().map_err(|e| e.to_string())?;
    let s = PipewireSink::open(&program, width, height, fps, mode).map_err(|e| e.to_string())?;
    tracing::info!(
        device = %s.info().device,
        "publishing as a PipeWire camera: e.g. gst-launch-1.0 pipewiresrc target-object={VIEW_NODE} ! videoconvert ! autovideosink"
    );
    Ok(Box::new(s))
}

/// The output sink, and for `auto` why it was chosen (shown in the log and
/// in `sdictl status`'s Device).
pub fn open(
    c: &Config,
    width: usize,
    height: usize,
    fps: f64,
    mode: ModeId,
) -> Result<(Box<dyn Sink>, Option<String>), String> {
    let kind = c.output.sink;
    let auto = kind == SinkKind::Auto;
    let mut passed = Vec::new();
    if auto || kind == SinkKind::Loopback {
        match LoopbackSink::open(&c.output.label, &c.output.data_label, width, height, fps) {
            Ok(s) => {
                tracing::info!(device = %s.info().device, "publishing on v4l2loopback");
                let why = auto.then(|| {
                    format!(
                        "auto: v4l2loopback device labelled \"{}\" found",
                        c.output.label
                    )
                });
                return Ok((Box::new(s), why));
            }
            Err(e) if !auto => return Err(e.to_string()),
            Err(e) => {
                tracing::warn!(
                    "{e}\nNo usable v4l2loopback device labelled \"{}\". To publish a V4L2 camera: sudo apt install v4l2loopback-dkms && sudo {}\nTrying PipeWire, then a y4m stream.",
                    c.output.label,
                    v4l2loopback_glue::modprobe_command(&c.output.label)
                );
                passed.push(format!(
                    "no v4l2loopback device labelled \"{}\"",
                    c.output.label
                ));
            }
        }
    }
    if auto || kind == SinkKind::Pipewire {
        match open_pipewire(width, height, fps, mode) {
            Ok(s) => {
                let why = auto.then(|| format!("auto: {}; PipeWire reachable", passed.join("; ")));
                return Ok((s, why));
            }
            Err(e) if !auto => return Err(e),
            Err(e) => {
                tracing::info!("PipeWire sink unavailable ({e}); falling back to a y4m stream");
                passed.push(e);
            }
        }
    }
    let path = (!c.output.y4m_path.is_empty()).then(|| PathBuf::from(&c.output.y4m_path));
    let sink = Y4mSink::new(path.as_deref(), width, height, fps)
        .map_err(|e| format!("y4m output: {e}"))?;
    let loc = sink.location();
    if loc == "stdout" {
        tracing::info!("streaming y4m on stdout (e.g. sdid ... | ffplay -i -)");
    } else {
        tracing::info!("streaming y4m into the FIFO {loc}: watch with `ffplay {loc}`");
        eprintln!("sdid: view the stream with: ffplay {loc}");
    }
    Ok((
        Box::new(sink),
        auto.then(|| format!("auto: {}", passed.join("; "))),
    ))
}
