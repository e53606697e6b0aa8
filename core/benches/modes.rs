//! Mode pipeline and display throughput, frames per second on one core, at
//! 320x240 and 640x480; side by side, the robust auto range against a
//! reference that sorts |x| to take the same percentile.
//!
//! Run: `cargo bench -p sdi-core --bench modes` (one element = one frame).

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use sdi_core::display::{robust_max_abs, DisplayMap, AUTO_PERCENTILE};
use sdi_core::image::Image;
use sdi_core::mode::{build_pipeline, ModeId, PipelineConfig};
use sdi_core::Frame;

fn noisy_frame(w: usize, h: usize, sequence: u64) -> Frame {
    let mut f = Frame::new(w, h);
    // Deterministic pseudo-noise, cheap to make.
    let mut s = 0x9E37_79B9u32 ^ sequence as u32;
    for v in &mut f.dn.data {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        *v = (s % 401) as f32 - 200.0;
    }
    f.sequence = sequence;
    f
}

fn sorted_percentile(data: &[f32]) -> f32 {
    let mut abs: Vec<f32> = data
        .iter()
        .filter(|v| v.is_finite())
        .map(|v| v.abs())
        .collect();
    abs.sort_unstable_by(f32::total_cmp);
    let k = ((AUTO_PERCENTILE * abs.len() as f64).ceil() as usize).clamp(1, abs.len()) - 1;
    abs[k]
}

fn bench_modes(c: &mut Criterion) {
    let mut group = c.benchmark_group("mode");
    group
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_millis(300))
        .sample_size(20)
        .throughput(Throughput::Elements(1));
    for (w, h) in [(320, 240), (640, 480)] {
        let frames = [noisy_frame(w, h, 0), noisy_frame(w, h, 1)];
        for mode in [ModeId::BipolarColour, ModeId::TwoShot] {
            let mut p = build_pipeline(
                mode,
                PipelineConfig {
                    dark_frame_dn: Some(Image::filled(w, h, 3.0)),
                    ..Default::default()
                },
            );
            let mut i = 0usize;
            group.bench_function(BenchmarkId::new(mode.name(), format!("{w}x{h}")), |b| {
                b.iter(|| {
                    i += 1;
                    p.process(&frames[i & 1]).is_some()
                })
            });
        }
        let img = frames[0].dn.clone();
        let map = DisplayMap::default();
        let mut rgb = vec![0u8; w * h * 3];
        group.bench_function(BenchmarkId::new("display-rgb8", format!("{w}x{h}")), |b| {
            b.iter(|| map.render_rgb8(&img, &mut rgb))
        });
        group.bench_function(BenchmarkId::new("auto-range", format!("{w}x{h}")), |b| {
            b.iter(|| robust_max_abs(&img.data))
        });
        group.bench_function(
            BenchmarkId::new("auto-range-sorted-reference", format!("{w}x{h}")),
            |b| b.iter(|| sorted_percentile(&img.data)),
        );
    }
    group.finish();
}

criterion_group!(benches, bench_modes);
criterion_main!(benches);
