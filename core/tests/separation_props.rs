//! Property tests: invariants of the separation estimators on arbitrary input.

use proptest::prelude::*;
use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    auto_segment, bilateral_exact, bilateral_grid, bilateral_separable, pool_moments,
    segment_moments, skellam_ml_pixel, unmix, BilateralParams, MlMethod, Moments, PoolParams,
    SegmentParams, SeparationError, SlidingWelford, UnmixOptions, Welford,
};
use sdi_core::{Frame, Image, PixelFlags};

fn value() -> impl Strategy<Value = f32> {
    prop_oneof![
        20 => -3000.0f32..3000.0,
        // 1e7 electrons at unit gain.
        2 => -1e7f32..1e7,
        1 => Just(f32::NEG_INFINITY),
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(0.0f32),
    ]
}

fn frame_of(w: usize, h: usize) -> impl Strategy<Value = Frame> {
    (
        prop::collection::vec(value(), w * h),
        prop::collection::vec(prop::bool::weighted(0.1), w * h),
    )
        .prop_map(move |(dn, sat)| {
            let mut f = Frame::new(w, h);
            f.dn.data = dn;
            f.saturated.data = sat.into_iter().map(u8::from).collect();
            f
        })
}

fn frame() -> impl Strategy<Value = Frame> {
    (1usize..9, 1usize..9).prop_flat_map(|(w, h)| frame_of(w, h))
}

/// `n` frames of one size (up to 6 x 6).
fn frames(n: std::ops::Range<usize>) -> impl Strategy<Value = Vec<Frame>> {
    (1usize..7, 1usize..7, n).prop_flat_map(|(w, h, n)| prop::collection::vec(frame_of(w, h), n))
}

fn welford(fs: &[Frame]) -> Result<Moments, SeparationError> {
    let mut acc = Welford::new(fs[0].width(), fs[0].height());
    for f in fs {
        acc.push(f)?;
    }
    acc.moments()
}

/// No NaN from `unmix` on `m`, plain or non-negative, and non-negative when asked.
fn unmixes_cleanly(m: &Moments, h: &SkellamMixing) -> Result<(), TestCaseError> {
    for nonnegative in [false, true] {
        let opts = UnmixOptions {
            subtract_read_noise: true,
            nonnegative,
        };
        let sep = unmix(m, h, opts).unwrap();
        for i in 0..m.mean_dn.len() {
            let (a, b) = (sep.i_plus_electrons.data[i], sep.i_minus_electrons.data[i]);
            prop_assert!(a.is_finite() && b.is_finite());
            prop_assert!(!sep.i_plus_se_electrons.data[i].is_nan());
            prop_assert!(!nonnegative || (a >= 0.0 && b >= 0.0));
        }
    }
    Ok(())
}

fn h() -> impl Strategy<Value = SkellamMixing> {
    (1e-6f64..2.0, 0.0f64..500.0).prop_map(|(g, r)| SkellamMixing::new(g, r))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn no_nan_and_nonnegative_when_promised(f in frame(), h in h(), sd in 0.3f64..4.0, sr in 0.01f64..1e4) {
        let p = BilateralParams::new(sd, sr);
        let labels = Image { width: f.width(), height: f.height(), data: (0..f.dn.len() as u32).map(|i| i % 3).collect() };
        for m in [bilateral_exact(&f, p).unwrap(), bilateral_separable(&f, p).unwrap(), bilateral_grid(&f, p).unwrap(), segment_moments(&f, &labels, None).unwrap(), {
            let seg = auto_segment(&f, SegmentParams::default()).unwrap();
            segment_moments(&f, &seg.labels, Some(&seg.interior)).unwrap()
        }] {
            for nonnegative in [false, true] {
                let sep = unmix(&m, &h, UnmixOptions { subtract_read_noise: true, nonnegative }).unwrap();
                for i in 0..f.dn.len() {
                    let (a, b) = (sep.i_plus_electrons.data[i], sep.i_minus_electrons.data[i]);
                    prop_assert!(a.is_finite() && b.is_finite());
                    prop_assert!(!sep.i_plus_se_electrons.data[i].is_nan());
                    if nonnegative {
                        prop_assert!(a >= 0.0 && b >= 0.0);
                    }
                    if !f.dn.data[i].is_finite() {
                        prop_assert!(sep.flags.data[i] & PixelFlags::NONFINITE.bits() != 0);
                    }
                }
            }
        }
    }

    #[test]
    fn difference_matches_mean_unless_projected(fs in frames(2..4), h in h()) {
        let (f, p) = (&fs[0], BilateralParams::new(1.5, 500.0));
        let labels = Image::filled(f.width(), f.height(), 0);
        let welford = welford(&fs).unwrap();
        let pooled = pool_moments(&welford, PoolParams::default()).unwrap();
        let g = h.gain_dn_per_electron;
        for m in [bilateral_exact(f, p).unwrap(), bilateral_separable(f, p).unwrap(), bilateral_grid(f, p).unwrap(), segment_moments(f, &labels, None).unwrap(), welford, pooled] {
            let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
            for i in 0..f.dn.len() {
                if sep.flags.data[i] & (PixelFlags::INSUFFICIENT.bits() | PixelFlags::PROJECTED.bits()) == 0 {
                    let d = (sep.i_plus_electrons.data[i] - sep.i_minus_electrons.data[i]) as f64;
                    let want = m.mean_dn.data[i] / g;
                    // Outputs are f32: the difference is resolved to ~1e-6 of the larger channel.
                    let scale = (sep.i_plus_electrons.data[i].abs().max(sep.i_minus_electrons.data[i].abs()) as f64).max(want.abs()).max(1.0);
                    prop_assert!((d - want).abs() <= 1e-5 * scale, "{d} vs {want}");
                }
            }
        }
    }

    #[test]
    fn welford_matches_two_pass(xs in prop::collection::vec(-1e6f32..1e6, 2..60)) {
        let mut acc = Welford::new(1, 1);
        for &x in &xs {
            let mut f = Frame::new(1, 1);
            f.dn.data[0] = x;
            acc.push(&f).unwrap();
        }
        let n = xs.len() as f64;
        let mean = xs.iter().map(|&x| x as f64).sum::<f64>() / n;
        let var = xs.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let m = acc.moments().unwrap();
        prop_assert!((m.mean_dn.data[0] - mean).abs() <= 1e-9 * mean.abs().max(1.0));
        prop_assert!((m.variance_dn2.data[0] - var).abs() <= 1e-9 * var.max(1.0));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn pooling_keeps_moments_sane(fs in frames(2..6), h in h(), radius_px in 0usize..4, tolerance_sigmas in 0.5f64..5.0) {
        let m = welford(&fs).unwrap();
        let p = pool_moments(&m, PoolParams { radius_px, tolerance_sigmas }).unwrap();
        if radius_px == 0 {
            prop_assert_eq!(&p, &m);
        }
        let (w, ht) = (m.width(), m.height());
        let ok = |i: usize| m.flags.data[i] & PixelFlags::INSUFFICIENT.bits() == 0;
        for i in 0..w * ht {
            prop_assert_eq!(p.flags.data[i] & m.flags.data[i], m.flags.data[i]);
            if !ok(i) {
                // Neither pooled nor changed.
                prop_assert_eq!((p.mean_dn.data[i], p.samples.data[i]), (m.mean_dn.data[i], m.samples.data[i]));
                continue;
            }
            prop_assert!(p.mean_dn.data[i].is_finite() && p.variance_dn2.data[i].is_finite());
            prop_assert!(p.variance_dn2.data[i] >= 0.0 && p.mean_var_dn2.data[i] >= 0.0);
            prop_assert!(!p.variance_var_dn4.data[i].is_nan() && !p.mean_variance_cov_dn3.data[i].is_nan());
            prop_assert!(p.samples.data[i] >= m.samples.data[i]);
            // The pooled mean lies among the usable means of the window.
            let (x, y) = (i % w, i / w);
            let window = (y.saturating_sub(radius_px)..(y + radius_px + 1).min(ht))
                .flat_map(|yy| (x.saturating_sub(radius_px)..(x + radius_px + 1).min(w)).map(move |xx| yy * w + xx))
                .filter(|&j| ok(j));
            let (lo, hi) = window.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), j| (lo.min(m.mean_dn.data[j]), hi.max(m.mean_dn.data[j])));
            let slack = 1e-9 * lo.abs().max(hi.abs()).max(1.0);
            prop_assert!(p.mean_dn.data[i] >= lo - slack && p.mean_dn.data[i] <= hi + slack);
        }
        unmixes_cleanly(&p, &h)?;
    }

    #[test]
    fn sliding_window_is_welford_over_the_window(fs in frames(1..10), window in 2usize..5) {
        let mut s = SlidingWelford::new(fs[0].width(), fs[0].height(), window).unwrap();
        // Removing a sample x costs ~eps x^2 in the variance until the next rebuild.
        let mut big = 0.0f64;
        for k in 0..fs.len() {
            s.push(&fs[k]).unwrap();
            for (x, &sat) in fs[k].dn.data.iter().zip(&fs[k].saturated.data) {
                if sat == 0 && x.is_finite() {
                    big = big.max((*x as f64).abs());
                }
            }
            let want = welford(&fs[(k + 1).saturating_sub(window)..=k]);
            let got = s.moments();
            let (Ok(got), Ok(want)) = (got.clone(), want.clone()) else {
                prop_assert_eq!(got.err(), want.err());
                continue;
            };
            // Flags describe the frames in the window, not older ones.
            prop_assert_eq!(&got.flags, &want.flags);
            prop_assert_eq!(&got.samples, &want.samples);
            for i in 0..got.mean_dn.len() {
                let (a, b) = (got.mean_dn.data[i], want.mean_dn.data[i]);
                prop_assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0) + 1e-13 * big, "mean {} vs {}", a, b);
                let (a, b) = (got.variance_dn2.data[i], want.variance_dn2.data[i]);
                prop_assert!((a - b).abs() <= 1e-6 * b.max(1.0) + 1e-13 * big * big, "variance {} vs {}", a, b);
                prop_assert!(!got.variance_var_dn4.data[i].is_nan() && !got.mean_variance_cov_dn3.data[i].is_nan());
            }
        }
    }

    #[test]
    fn skellam_ml_is_nonnegative_or_refuses(
        xs in prop::collection::vec(prop_oneof![20 => -1e4f64..1e4, 1 => Just(f64::NAN), 1 => Just(f64::INFINITY)], 0..12),
        log_g in -12.0f64..0.5,
        r in prop_oneof![Just(0.0f64), 0.0f64..100.0],
    ) {
        let g = 10f64.powf(log_g);
        match skellam_ml_pixel(&xs, &SkellamMixing::new(g, r)) {
            Ok(fit) => {
                let (p, m) = (fit.i_plus_electrons, fit.i_minus_electrons);
                prop_assert!(p.is_finite() && m.is_finite() && p >= 0.0 && m >= 0.0, "{:?}", fit);
                prop_assert_eq!(fit.samples, xs.iter().filter(|x| x.is_finite()).count());
                if fit.method == MlMethod::SkellamCounts {
                    // I+ - I- = mean count.
                    let k: Vec<f64> = xs.iter().filter(|x| x.is_finite()).map(|x| (x / g).round()).collect();
                    let mean = k.iter().sum::<f64>() / k.len() as f64;
                    prop_assert!((p - m - mean).abs() <= 1e-6 * (1.0 + p + m), "{:?} vs {}", fit, mean);
                }
            }
            Err(e) => prop_assert!(matches!(e, SeparationError::TooFewFrames { .. } | SeparationError::Parameter { .. }), "{}", e),
        }
    }
}
