//! `sdictl status`: the daemon's properties as a few lines a person reads,
//! in the manner of `systemctl status`; `--json` prints them raw.

use sdi_api::{Camera1Proxy, Properties, Stats};
use sdi_core::number::Number;
use serde_json::Value as Json;

use super::units::{duration_us, hz};
use super::wire_json;
use crate::exit::CliError;
use crate::stdout::outln;

pub async fn run(camera: &Camera1Proxy<'_>, json: bool) -> Result<(), CliError> {
    let p = Properties::read(camera).await?;
    if json {
        outln!("{}", Json::Object(wire_json::object(&p)?))?;
    } else {
        for line in lines(&p) {
            outln!("{line}")?;
        }
    }
    Ok(())
}

/// The status as lines: a headline, then one labelled line per aspect.
pub fn lines(p: &Properties) -> Vec<String> {
    let (sensor, output) = p.device.split_once(" -> ").unwrap_or((&p.device, ""));
    let mut lines = vec![format!(
        "sdid: {}, mode {} ({})",
        state(&p.stats),
        p.mode,
        source(p)
    )];
    let mut line = |label: &str, text: String| lines.push(format!("{label:>11}: {text}"));
    line("camera", p.serial.clone());
    line("sensor", sensor.to_owned());
    line("setup", setup(p));
    line(
        "capture",
        format!(
            "exposure {} us, {:.1} fps, modulation {}",
            Number(p.exposure_us),
            p.frame_rate,
            hz(p.modulation_hz)
        ),
    );
    line(
        "view",
        format!("colormap {}, range {}", p.colormap, range(p.range)),
    );
    line(
        "output",
        format!(
            "{}, {} {}x{}",
            sink(&p.sink, output),
            p.format,
            p.width,
            p.height
        ),
    );
    if !p.recording.is_empty() {
        line("recording", p.recording.clone());
    }
    if !p.job.name.is_empty() {
        line(
            "job",
            format!(
                "{}, frame {} of {}",
                p.job.name, p.job.frames_done, p.job.frames_total
            ),
        );
    }
    line("stats", stats(&p.stats));
    if p.backend == "opt8241" {
        line("limits", limits(p));
    }
    if p.stats.board_temperature_c.is_finite() || p.stats.output_overflows > 0 {
        line("board", board(&p.stats));
    }
    if !p.stats.device_state.is_empty() {
        line("source", p.stats.device_state.clone());
    }
    if !p.stats.recording_stopped.is_empty() {
        line(
            "stopped",
            format!("recording stopped: {}", p.stats.recording_stopped),
        );
    }
    if let Some(w) = light_travel_warning(p) {
        line("warning", w);
    }
    lines
}

/// The setters' ranges, as the board allows them.
fn limits(p: &Properties) -> String {
    let r = |key: &str, unit: &str| match p.limits.get(key) {
        Some((lo, hi)) => format!("{} to {} {unit}", Number(*lo), Number(*hi)),
        None => "?".into(),
    };
    format!(
        "frame rate {}, exposure {}, modulation {}",
        r("FrameRate", "Hz"),
        r("ExposureUs", "us"),
        r("ModulationHz", "Hz")
    )
}

/// Temperatures and output overflows of the board.
fn board(s: &Stats) -> String {
    format!(
        "sensor {} C, illumination {} C, {} output overflow(s)",
        Number(s.board_temperature_c),
        Number(s.illumination_temperature_c),
        s.output_overflows
    )
}

/// Streaming, or why not.
fn state(s: &Stats) -> &'static str {
    if !s.device_available {
        "no frames"
    } else if s.frames == 0 {
        "waiting for the first frame"
    } else if s.fps == 0.0 {
        "stalled"
    } else {
        "streaming"
    }
}

/// The sink and where it publishes, in words.
fn sink(kind: &str, output: &str) -> String {
    match kind {
        "loopback" => format!("v4l2loopback {output}"),
        "pipewire" => format!("PipeWire camera, node {output}"),
        "y4m" => format!("y4m stream {output}"),
        _ => output.to_owned(),
    }
}

/// Where frames come from: the backend in words, and the simulator's scene.
fn source(p: &Properties) -> String {
    let backend = match p.backend.as_str() {
        "sim" => "simulator",
        "replay" => "replay of a recording",
        "opt8241" => "OPT8241 board",
        other => other,
    };
    match p.scene.is_empty() {
        true => backend.to_owned(),
        false => format!("{backend}, scene {}", p.scene),
    }
}

fn setup(p: &Properties) -> String {
    let part = |key: &str| p.setup.get(key).map(String::as_str).unwrap_or("?");
    format!(
        "LS1 {}; LS2 {}; optics {}",
        part("ls1"),
        part("ls2"),
        part("optics")
    )
}

/// The display range: 0 is the symmetric automatic one.
fn range(max_abs_dn: f64) -> String {
    match max_abs_dn == 0.0 {
        true => "auto".into(),
        false => format!("{} DN", Number(max_abs_dn)),
    }
}

fn stats(s: &Stats) -> String {
    let dropped = s.dropped_view + s.dropped_recording;
    format!(
        "{:.1} fps, latency {} (max {}), {dropped} dropped, {} frames",
        s.fps,
        duration_us(s.latency_us),
        duration_us(s.latency_max_us),
        s.frames
    )
}

/// The simulator's light-travel warning for the scene it shows at the
/// current modulation frequency; none for other sources (sdid does not know
/// a real scene's depth).
fn light_travel_warning(p: &Properties) -> Option<String> {
    let scene = sdi_core::scene::SceneSpec::from_name(&p.scene)?;
    sdi_core::simulator::light_travel::light_travel_warning(&scene, p.modulation_hz)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn raw_on_the_simulator() -> Properties {
        Properties {
            mode: "raw".into(),
            modes: vec!["raw".into()],
            setup: HashMap::from([
                ("ls1".into(), "any source, in phase".into()),
                ("ls2".into(), "any source, out of phase".into()),
                ("optics".into(), "none".into()),
            ]),
            serial: "sim-0".into(),
            backend: "sim".into(),
            scene: "flat-field".into(),
            device: "simulator (sdi-sim) -> /dev/video10".into(),
            sink: "loopback".into(),
            format: "YUYV".into(),
            width: 640,
            height: 480,
            frame_rate: 60.0,
            exposure_us: 1000.0,
            modulation_hz: 12e6,
            colormap: "diverging".into(),
            range: 0.0,
            recording: String::new(),
            limits: HashMap::new(),
            job: Default::default(),
            stats: Stats {
                frames: 123,
                fps: 60.001376238018075,
                latency_us: 76.2,
                latency_max_us: 1250.0,
                device_available: true,
                ..Stats::default()
            },
        }
    }

    #[test]
    fn reads_in_words_and_units() {
        let text = lines(&raw_on_the_simulator()).join("\n");
        assert_eq!(
            text,
            "sdid: streaming, mode raw (simulator, scene flat-field)\n\
             \x20    camera: sim-0\n\
             \x20    sensor: simulator (sdi-sim)\n\
             \x20     setup: LS1 any source, in phase; LS2 any source, out of phase; optics none\n\
             \x20   capture: exposure 1000 us, 60.0 fps, modulation 12 MHz\n\
             \x20      view: colormap diverging, range auto\n\
             \x20    output: v4l2loopback /dev/video10, YUYV 640x480\n\
             \x20     stats: 60.0 fps, latency 76 us (max 1.2 ms), 0 dropped, 123 frames"
        );
    }

    #[test]
    fn warns_of_light_travel_only_where_the_scene_has_depth() {
        let mut p = raw_on_the_simulator();
        assert!(!lines(&p).join("\n").contains("light travel"));
        p.scene = "depth-edge".into();
        let text = lines(&p).join("\n");
        assert!(text.contains("warning: light travel"), "{text}");
        p.scene = String::new();
        assert!(!lines(&p).join("\n").contains("light travel"));
    }

    #[test]
    fn a_running_job_is_a_line_of_its_own() {
        let mut p = raw_on_the_simulator();
        p.job = sdi_api::JobProgress {
            name: "calibration".into(),
            frames_done: 12,
            frames_total: 360,
        };
        let text = lines(&p).join("\n");
        assert!(text.contains("job: calibration, frame 12 of 360"), "{text}");
    }
}
