//! Bytes and CPU per recorded frame: format version 1 (f32 samples, as
//! recorded before) side by side with version 2 (i16 samples, zstd) in one
//! run, on simulated 320x240 frames of the TI sensor: a static scene, a
//! moving one, dark frames, and the board's half-DN two-quad mean.
//!
//! Run: `cargo bench -p sdi-recording --bench frame_encoding`. Times are the
//! bench thread's CPU time (one core's work), so other processes on the
//! machine do not inflate them.

use std::time::Duration;

use nix::time::{clock_gettime, ClockId};
use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;
use sdi_recording::format::{self, Record};

const FRAMES: usize = 120;
const FPS: f64 = 60.0;

fn thread_cpu() -> Duration {
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(Duration::from)
        .unwrap_or_default()
}

fn frames(scene: &str, dark: bool, half_dn: bool) -> Vec<Frame> {
    let sensor = SensorPreset::TiOpt8241.params();
    let carrier = sensor.modulation_hz;
    let Some(spec) = SceneSpec::from_name(scene) else {
        return Vec::new();
    };
    let Ok(mut sim) = Simulator::new(SimConfig::new(sensor.clone(), spec)) else {
        return Vec::new();
    };
    let illumination = if scene == "fan-pellets" {
        Illumination {
            modulation: ModulationPattern::single_transition(0.5),
            ls1: SourceDrive::Off,
            ls2: SourceDrive::Off,
        }
    } else {
        Illumination::snapshot(carrier)
    };
    (0..FRAMES)
        .map(|i| {
            let mut f = Frame::new(sensor.width, sensor.height);
            if dark {
                sim.capture_dark(&mut f);
            } else {
                sim.capture(&illumination, &mut f);
            }
            if half_dn {
                f.dn.data.iter_mut().for_each(|v| *v *= 0.5);
            }
            f.sequence = i as u64 + 1;
            f
        })
        .collect()
}

struct Row {
    bytes: usize,
    encode: Duration,
    decode: Duration,
}

fn measure(frames: &[Frame], v2: bool) -> Row {
    let (mut out, mut scratch) = (Vec::new(), Vec::new());
    let mut payloads = Vec::with_capacity(frames.len());
    let t0 = thread_cpu();
    for f in frames {
        if v2 {
            format::encode_frame("raw", f, &mut out, &mut scratch);
        } else {
            format::encode_frame_v1("raw", f, &mut out);
        }
        payloads.push(out.clone());
    }
    let encode = thread_cpu() - t0;
    let size = (frames[0].width(), frames[0].height());
    let kind = if v2 {
        format::KIND_FRAME
    } else {
        format::KIND_FRAME_V1
    };
    // one decoder for the run, as a reader keeps one
    let mut decoder = format::Decoder::default();
    let t0 = thread_cpu();
    for (p, f) in payloads.iter().zip(frames) {
        match decoder.decode(kind, p, size) {
            Ok(Record::Frame { frame, .. }) => assert_eq!(frame.sequence, f.sequence),
            other => panic!("decode failed: {other:?}"),
        }
    }
    let decode = thread_cpu() - t0;
    // record overhead: magic, kind, length, CRC
    let bytes = payloads.iter().map(|p| p.len() + 13).sum::<usize>() / frames.len();
    Row {
        bytes,
        encode: encode / frames.len() as u32,
        decode: decode / frames.len() as u32,
    }
}

fn main() {
    println!(
        "{:<28} {:>9} {:>9} {:>6} {:>10} {:>10} {:>10} {:>10} {:>9} {:>9}",
        "320x240 frames",
        "v1 B/fr",
        "v2 B/fr",
        "ratio",
        "v1 enc us",
        "v2 enc us",
        "v1 dec us",
        "v2 dec us",
        "v1 GB/h",
        "v2 GB/h"
    );
    for (name, scene, dark, half) in [
        ("static (colour-chart)", "colour-chart", false, false),
        ("moving (fan-pellets)", "fan-pellets", false, false),
        ("dark", "colour-chart", true, false),
        ("board half-DN (static)", "colour-chart", false, true),
    ] {
        let f = frames(scene, dark, half);
        if f.is_empty() {
            println!("{name}: scene {scene} unknown");
            continue;
        }
        let (a, b) = (measure(&f, false), measure(&f, true));
        let gb_h = |bytes: usize| bytes as f64 * FPS * 3600.0 / 1e9;
        println!(
            "{:<28} {:>9} {:>9} {:>5.2}x {:>10.0} {:>10.0} {:>10.0} {:>10.0} {:>9.1} {:>9.1}",
            name,
            a.bytes,
            b.bytes,
            a.bytes as f64 / b.bytes as f64,
            a.encode.as_secs_f64() * 1e6,
            b.encode.as_secs_f64() * 1e6,
            a.decode.as_secs_f64() * 1e6,
            b.decode.as_secs_f64() * 1e6,
            gb_h(a.bytes),
            gb_h(b.bytes),
        );
    }
}
