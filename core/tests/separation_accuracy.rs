//! Accuracy against ground truth on a patchwork test chart: M1 error falls as
//! 1/sqrt(N) and matches its own standard errors, the paper's ordering
//! M1 < M2 < M3 holds, and the fast M3 stays close to the exact one.

mod separation_support;

use sdi_core::separation::{
    auto_segment, bilateral_exact, bilateral_separable, segment_moments, unmix, BilateralParams,
    LiveMethod, LiveSeparator, SegmentParams, UnmixOptions, Welford,
};
use sdi_core::Image;
use separation_support::{chart, rel_rmse_bias, ti_h, Sampler, Truth};

fn m1_rmse(t: &Truth, n: usize, seed: u64) -> (f64, f64, f64) {
    let h = ti_h();
    let mut s = Sampler::new(h, seed);
    let mut acc = Welford::new(t.width, t.height);
    for _ in 0..n {
        acc.push(&s.frame(t)).unwrap();
    }
    let sep = unmix(&acc.moments().unwrap(), &h, UnmixOptions::default()).unwrap();
    let (rp, _) = rel_rmse_bias(&sep.i_plus_electrons, &t.i_plus);
    let (rm, _) = rel_rmse_bias(&sep.i_minus_electrons, &t.i_minus);
    // Predicted relative RMSE from the estimator's own standard errors.
    let se2 = sep
        .i_plus_se_electrons
        .data
        .iter()
        .map(|&v| (v as f64).powi(2))
        .sum::<f64>()
        / t.i_plus.len() as f64;
    let mean_t = t.i_plus.iter().sum::<f64>() / t.i_plus.len() as f64;
    (rp, rm, se2.sqrt() / mean_t)
}

#[test]
fn m1_error_falls_as_one_over_sqrt_n_and_matches_its_standard_errors() {
    let t = chart(6, 4, 6, 20_000.0);
    let (p100, m100, se100) = m1_rmse(&t, 100, 11);
    let (p400, m400, _) = m1_rmse(&t, 400, 12);
    let (p1000, m1000, se1000) = m1_rmse(&t, 1000, 13);
    eprintln!("M1 rel RMSE I+/I-: N=100 {p100:.4}/{m100:.4}  N=400 {p400:.4}/{m400:.4}  N=1000 {p1000:.4}/{m1000:.4}");
    let r = p100 / p400;
    assert!((1.6..2.5).contains(&r), "N=100 -> 400 ratio {r}");
    let r = m100 / m1000;
    assert!((2.5..3.9).contains(&r), "N=100 -> 1000 ratio {r}");
    // Standard errors are calibrated: predicted and observed RMSE within 15%.
    assert!((p100 / se100 - 1.0).abs() < 0.15, "{p100} vs {se100}");
    assert!((p1000 / se1000 - 1.0).abs() < 0.15, "{p1000} vs {se1000}");
}

#[test]
fn ordering_m1_m2_m3_on_a_chart() {
    let h = ti_h();
    // 8x8 px patches: M2 averages 64 pixels, M1 1000 frames.
    let t = chart(6, 4, 8, 20_000.0);
    let mut s = Sampler::new(h, 21);
    let mut acc = Welford::new(t.width, t.height);
    for _ in 0..1000 {
        acc.push(&s.frame(&t)).unwrap();
    }
    let f = s.frame(&t);
    let m1 = unmix(&acc.moments().unwrap(), &h, UnmixOptions::default()).unwrap();
    // Pre-segmented by hand, as in the paper.
    let labels = Image {
        width: t.width,
        height: t.height,
        data: (0..t.width * t.height)
            .map(|i| ((i / t.width) / 8 * 6 + (i % t.width) / 8) as u32)
            .collect(),
    };
    let m2 = unmix(
        &segment_moments(&f, &labels, None).unwrap(),
        &h,
        UnmixOptions::default(),
    )
    .unwrap();
    let m3 = unmix(
        &bilateral_exact(&f, BilateralParams::new(2.0, 30.0)).unwrap(),
        &h,
        UnmixOptions::default(),
    )
    .unwrap();
    let e = |img: &Image<f32>, t: &[f64]| rel_rmse_bias(img, t).0;
    let (e1, e2, e3) = (
        e(&m1.i_plus_electrons, &t.i_plus) + e(&m1.i_minus_electrons, &t.i_minus),
        e(&m2.i_plus_electrons, &t.i_plus) + e(&m2.i_minus_electrons, &t.i_minus),
        e(&m3.i_plus_electrons, &t.i_plus) + e(&m3.i_minus_electrons, &t.i_minus),
    );
    eprintln!("sum of rel RMSE (I+ and I-): M1 {e1:.4}  M2 {e2:.4}  M3 {e3:.4}");
    assert!(e1 < e2 && e2 < e3);
}

/// Mean (DN rms) and variance (relative rms) differences of a fast M3
/// against the exact one on a 6x4 chart, for each (sigma_d, sigma_r).
fn m3_vs_exact(
    fast: impl Fn(&sdi_core::Frame, BilateralParams) -> sdi_core::separation::Moments,
    label: &str,
) -> Vec<(f64, f64, f64, f64)> {
    let h = ti_h();
    let t = chart(6, 4, 12, 20_000.0);
    let f = Sampler::new(h, 31).frame(&t);
    let mut out = Vec::new();
    for (sd, sr) in [(1.5, 20.0), (2.0, 40.0), (3.0, 80.0)] {
        let p = BilateralParams::new(sd, sr);
        let a = bilateral_exact(&f, p).unwrap();
        let b = fast(&f, p);
        let n = a.mean_dn.len() as f64;
        let rms = |x: &[f64], y: &[f64]| {
            (x.iter().zip(y).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / n).sqrt()
        };
        let scale_v = a.variance_dn2.data.iter().sum::<f64>() / n;
        let dm = rms(&a.mean_dn.data, &b.mean_dn.data);
        let dv = rms(&a.variance_dn2.data, &b.variance_dn2.data) / scale_v;
        eprintln!(
            "{label}sd {sd} sr {sr}: mean diff {dm:.3} DN rms, variance diff {:.2}% rms",
            100.0 * dv
        );
        out.push((sd, sr, dm, dv));
    }
    out
}

#[test]
fn separable_m3_is_close_to_exact() {
    for (_, _, dm, dv) in m3_vs_exact(|f, p| bilateral_separable(f, p).unwrap(), "") {
        assert!(dm < 2.0 && dv < 0.3, "{dm} {dv}");
    }
}

#[test]
fn live_separator_bilateral_and_sliding_window() {
    let h = ti_h();
    let t = chart(4, 3, 8, 10_000.0);
    let mut s = Sampler::new(h, 41);
    let mut live = LiveSeparator::new(
        LiveMethod::SlidingWindow { frames: 50 },
        h,
        UnmixOptions::default(),
    );
    assert!(live.process(&s.frame(&t)).unwrap().is_none());
    for _ in 0..120 {
        live.process(&s.frame(&t)).unwrap();
    }
    let sep = live.last().unwrap();
    let (rp, _) = rel_rmse_bias(&sep.i_plus_electrons, &t.i_plus);
    // 50 frames: sqrt(2/49) relative noise on I+ + I-, so below ~0.35 on I+.
    assert!(rp < 0.35, "{rp}");
    let mut live = LiveSeparator::new(
        LiveMethod::Bilateral(BilateralParams::new(2.0, 30.0)),
        h,
        UnmixOptions {
            nonnegative: true,
            ..Default::default()
        },
    );
    let sep = live.process(&s.frame(&t)).unwrap().unwrap();
    assert!(sep.i_plus_electrons.data.iter().all(|&v| v >= 0.0));
    // A frame of another size restarts the window instead of failing.
    let mut live = LiveSeparator::new(
        LiveMethod::SlidingWindow { frames: 5 },
        h,
        UnmixOptions::default(),
    );
    live.process(&s.frame(&t)).unwrap();
    let small = chart(1, 1, 4, 100.0);
    assert!(live.process(&s.frame(&small)).unwrap().is_none());
}

#[test]
fn auto_segmentation_finds_the_patches_of_a_chart() {
    let h = ti_h();
    let t = chart(6, 4, 16, 20_000.0);
    let f = Sampler::new(h, 51).frame(&t);
    let seg = auto_segment(&f, SegmentParams::default()).unwrap();
    let distinct: std::collections::HashSet<u32> = seg.labels.data.iter().copied().collect();
    let sep = unmix(
        &segment_moments(&f, &seg.labels, Some(&seg.interior)).unwrap(),
        &h,
        UnmixOptions::default(),
    )
    .unwrap();
    let (rp, _) = rel_rmse_bias(&sep.i_plus_electrons, &t.i_plus);
    let hand = Image {
        width: t.width,
        height: t.height,
        data: (0..t.width * t.height)
            .map(|i| ((i / t.width) / 16 * 6 + (i % t.width) / 16) as u32)
            .collect(),
    };
    let sep = unmix(
        &segment_moments(&f, &hand, None).unwrap(),
        &h,
        UnmixOptions::default(),
    )
    .unwrap();
    let (rh, _) = rel_rmse_bias(&sep.i_plus_electrons, &t.i_plus);
    eprintln!(
        "auto segmentation: {} segments (24 patches), M2 rel RMSE I+ {rp:.4} (hand-drawn {rh:.4})",
        distinct.len()
    );
    assert!((20..=30).contains(&distinct.len()));
    // Eroded segments hold fewer pixels than hand-drawn ones: larger error.
    assert!(rp < 3.0 * rh, "{rp} vs {rh}");
}

#[test]
fn grid_m3_is_close_to_exact() {
    let grid = |f: &sdi_core::Frame, p| sdi_core::separation::bilateral_grid(f, p).unwrap();
    for (_, sr, dm, dv) in m3_vs_exact(grid, "grid ") {
        // Wide range kernels weigh the steps between patches, where the
        // grid's compact kernel and the exact Gaussian differ most.
        let dv_max = if sr > 50.0 { 1.0 } else { 0.2 };
        assert!(dm < 3.0 && dv < dv_max, "{dm} {dv}");
    }
}
