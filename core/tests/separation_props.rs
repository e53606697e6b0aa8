//! Property tests: invariants of the separation estimators on arbitrary input.

use proptest::prelude::*;
use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    bilateral_exact, bilateral_grid, bilateral_separable, flags, segment_moments, unmix,
    BilateralParams, UnmixOptions, Welford,
};
use sdi_core::{Frame, Image};

fn value() -> impl Strategy<Value = f32> {
    prop_oneof![
        20 => -3000.0f32..3000.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(0.0f32),
    ]
}

fn frame() -> impl Strategy<Value = Frame> {
    (1usize..9, 1usize..9).prop_flat_map(|(w, h)| {
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
    })
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
        for m in [bilateral_exact(&f, p).unwrap(), bilateral_separable(&f, p).unwrap(), bilateral_grid(&f, p).unwrap(), segment_moments(&f, &labels, None).unwrap()] {
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
                        prop_assert!(sep.flags.data[i] & flags::NONFINITE != 0);
                    }
                }
            }
        }
    }

    #[test]
    fn difference_matches_mean_unless_projected(f in frame(), h in h()) {
        let m = bilateral_exact(&f, BilateralParams::new(1.5, 500.0)).unwrap();
        let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
        let g = h.gain_dn_per_electron;
        for i in 0..f.dn.len() {
            if sep.flags.data[i] & (flags::INSUFFICIENT | flags::PROJECTED) == 0 {
                let d = (sep.i_plus_electrons.data[i] - sep.i_minus_electrons.data[i]) as f64;
                let want = m.mean_dn.data[i] / g;
                // Outputs are f32: the difference is resolved to ~1e-6 of the larger channel.
                let scale = (sep.i_plus_electrons.data[i].abs().max(sep.i_minus_electrons.data[i].abs()) as f64).max(want.abs()).max(1.0);
                prop_assert!((d - want).abs() <= 1e-5 * scale, "{d} vs {want}");
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
