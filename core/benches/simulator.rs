//! Simulator throughput, frames per second on one core: `capture()` at
//! 320x240 and 640x480 for a static scene (colour chart) and a moving one
//! (fan and pellets), and side by side the reference path that samples every
//! pixel with `rand_distr`'s Poisson and Normal.
//!
//! Run: `cargo bench -p sdi-core --bench simulator`. Times are the bench
//! thread's CPU time (CLOCK_THREAD_CPUTIME_ID), i.e. one core's work per
//! frame, unaffected by other processes competing for the machine; criterion
//! prints them as time per frame and as throughput in elements/s (one element
//! = one frame, so elem/s = frames/s).

mod support;

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;
use support::thread_cpu;

/// Runs `f` `iters` times and returns the CPU time it took.
fn cpu_time(iters: u64, mut f: impl FnMut()) -> Duration {
    let start = thread_cpu();
    for _ in 0..iters {
        f();
    }
    thread_cpu() - start
}

fn simulator(scene: &str, width: usize, height: usize) -> Simulator {
    let mut sensor = SensorPreset::TiOpt8241.params();
    sensor.width = width;
    sensor.height = height;
    let scene = SceneSpec::from_name(scene).expect("known scene");
    Simulator::new(SimConfig::new(sensor, scene)).expect("valid config")
}

fn illumination(scene: &str, carrier_hz: f64) -> Illumination {
    if scene == "fan-pellets" {
        Illumination {
            modulation: ModulationPattern::single_transition(0.5),
            ls1: SourceDrive::Off,
            ls2: SourceDrive::Off,
        }
    } else {
        Illumination::snapshot(carrier_hz)
    }
}

fn bench_capture(c: &mut Criterion) {
    let mut group = c.benchmark_group("capture");
    group
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_millis(500))
        .sample_size(20)
        .throughput(Throughput::Elements(1));
    for (w, h) in [(320, 240), (640, 480)] {
        for scene in ["colour-chart", "fan-pellets"] {
            let mut sim = simulator(scene, w, h);
            let light = illumination(scene, sim.params().modulation_hz);
            let mut frame = Frame::new(w, h);
            let id = format!("{scene}/{w}x{h}");
            group.bench_function(BenchmarkId::new("fast", &id), |b| {
                b.iter_custom(|n| cpu_time(n, || sim.capture(&light, &mut frame)))
            });
            let mut sim = simulator(scene, w, h);
            group.bench_function(BenchmarkId::new("rand_distr-reference", &id), |b| {
                b.iter_custom(|n| cpu_time(n, || sim.capture_reference(&light, &mut frame)))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_capture);
criterion_main!(benches);
