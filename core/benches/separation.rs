//! Criterion benchmarks of the separation estimators at 640x480 (M3) and
//! 320x240 (M1 push, M2).

use criterion::{criterion_group, criterion_main, Criterion};
use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    auto_segment, bilateral_separable, segment_moments, unmix, BilateralParams, SegmentParams,
    UnmixOptions, Welford,
};
use sdi_core::Frame;

fn frame(w: usize, h: usize) -> Frame {
    let mut f = Frame::new(w, h);
    let mut s = 12345u64;
    for (i, v) in f.dn.data.iter_mut().enumerate() {
        // Patches plus cheap pseudo-random noise (xorshift), about 8 DN rms.
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let noise = ((s % 2001) as f32 - 1000.0) * 0.014;
        let (x, y) = (i % w, i / w);
        *v = (((x * 6 / w) + 6 * (y * 4 / h)) as f32 * 37.0 - 400.0 + noise).round();
    }
    f
}

fn benches(c: &mut Criterion) {
    let h = SkellamMixing::new(0.052, 15.05);
    let big = frame(640, 480);
    c.bench_function("m3_separable_640x480_sd1.5", |b| {
        b.iter(|| bilateral_separable(&big, BilateralParams::new(1.5, 20.0)).unwrap())
    });
    c.bench_function("m3_separable_unmix_640x480_sd1.5", |b| {
        b.iter(|| {
            let m = bilateral_separable(&big, BilateralParams::new(1.5, 20.0)).unwrap();
            unmix(&m, &h, UnmixOptions::default()).unwrap()
        })
    });
    let small = frame(320, 240);
    let mut acc = Welford::new(320, 240);
    c.bench_function("m1_push_320x240", |b| b.iter(|| acc.push(&small).unwrap()));
    c.bench_function("m2_auto_segment_320x240", |b| {
        b.iter(|| {
            let seg = auto_segment(&small, SegmentParams::default()).unwrap();
            segment_moments(&small, &seg.labels, Some(&seg.interior)).unwrap()
        })
    });
}

criterion_group!(separation, benches);
criterion_main!(separation);
