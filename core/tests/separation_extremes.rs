//! Numerical stability of the separation estimators at the extremes.

mod separation_support;

use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    auto_segment, bilateral_exact, bilateral_grid, bilateral_separable, flags, segment_moments,
    unmix, BilateralParams, SegmentParams, SeparationError, UnmixOptions, Welford,
};
use sdi_core::{Frame, Image};
use separation_support::{chart, ti_h, Sampler, Truth};

fn flat(w: usize, h: usize, plus: f64, minus: f64) -> Truth {
    Truth {
        width: w,
        height: h,
        i_plus: vec![plus; w * h],
        i_minus: vec![minus; w * h],
    }
}

fn m1(s: &mut Sampler, t: &Truth, n: usize) -> Welford {
    let mut acc = Welford::new(t.width, t.height);
    for _ in 0..n {
        acc.push(&s.frame(t)).unwrap();
    }
    acc
}

fn all_finite(img: &Image<f32>) -> bool {
    img.data.iter().all(|v| !v.is_nan())
}

#[test]
fn tiny_eta_stays_finite_and_honest() {
    // eta = 1e-3: det H = 2 (rho eta)^3 ~ 1e-12.
    let h = SkellamMixing::new(0.08 * 1e-3, 15.05);
    assert!(h.determinant() < 1e-11);
    let t = flat(16, 16, 20_000.0, 10_000.0);
    let mut s = Sampler::new(h, 1);
    let m = m1(&mut s, &t, 400).moments().unwrap();
    let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
    let mut covered = 0;
    for i in 0..t.i_plus.len() {
        let (p, se) = (
            sep.i_plus_electrons.data[i],
            sep.i_plus_se_electrons.data[i],
        );
        assert!(p.is_finite() && se.is_finite() && se > 0.0);
        // The error bar is enormous and honest: truth within 4 SE.
        if ((p as f64) - 20_000.0).abs() < 4.0 * se as f64 {
            covered += 1;
        }
    }
    assert!(covered >= 250, "coverage {covered}/256");
    // Even g = 1e-12 inverts without NaN.
    let h = SkellamMixing::new(1e-12, 1.0);
    let (p, m) = h.inverse(1e-9, 2.0);
    assert!(p.is_finite() && m.is_finite());
}

#[test]
fn zero_photons_give_zero_within_errors_and_nonnegative_projection() {
    let h = ti_h();
    let t = flat(20, 20, 0.0, 0.0);
    let mut s = Sampler::new(h, 2);
    let m = m1(&mut s, &t, 200).moments().unwrap();
    let plain = unmix(&m, &h, UnmixOptions::default()).unwrap();
    let clamped = plain
        .flags
        .data
        .iter()
        .filter(|&&f| f & flags::VARIANCE_CLAMPED != 0)
        .count();
    assert!(
        clamped > 100,
        "about half the pixels dip below read noise: {clamped}"
    );
    for i in 0..400 {
        let (p, se) = (
            plain.i_plus_electrons.data[i],
            plain.i_plus_se_electrons.data[i],
        );
        assert!(p.abs() < 5.0 * se + 1e-3, "{p} +- {se}");
    }
    let nn = unmix(
        &m,
        &h,
        UnmixOptions {
            nonnegative: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(nn.i_plus_electrons.data.iter().all(|&v| v >= 0.0));
    assert!(nn.i_minus_electrons.data.iter().all(|&v| v >= 0.0));
}

#[test]
fn ten_million_electrons_no_cancellation() {
    // 24-bit ADC so 1e7 electrons fit; g = 0.25 DN/e.
    let h = SkellamMixing::new(0.25, 4.0);
    let t = flat(8, 8, 1e7, 5e6);
    let mut s = Sampler::new(h, 3);
    let m = m1(&mut s, &t, 500).moments().unwrap();
    let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
    let mean_p = sep
        .i_plus_electrons
        .data
        .iter()
        .map(|&v| v as f64)
        .sum::<f64>()
        / 64.0;
    let mean_m = sep
        .i_minus_electrons
        .data
        .iter()
        .map(|&v| v as f64)
        .sum::<f64>()
        / 64.0;
    // Per pixel sqrt(2/499) of 1.5e7 / 2 ~ 4.7e5; over 64 pixels ~ 6e4.
    assert!((mean_p - 1e7).abs() < 2.5e5, "{mean_p}");
    assert!((mean_m - 5e6).abs() < 2.5e5, "{mean_m}");
    // Welford against a large offset: f64 two-pass agrees to 1e-6 relative.
    let mut acc = Welford::new(1, 1);
    let xs: Vec<f64> = (0..1000).map(|k| 4e6 + ((k * 37) % 101) as f64).collect();
    for &x in &xs {
        let mut f = Frame::new(1, 1);
        f.dn.data[0] = x as f32;
        acc.push(&f).unwrap();
    }
    let mean = xs.iter().sum::<f64>() / 1000.0;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 999.0;
    let got = acc.moments().unwrap();
    assert!((got.variance_dn2.data[0] - var).abs() < 1e-6 * var);
}

#[test]
fn saturated_samples_are_excluded_and_flagged() {
    let h = ti_h();
    let t = flat(4, 4, 3000.0, 1000.0);
    let mut s = Sampler::new(h, 4);
    let mut acc = Welford::new(4, 4);
    for k in 0..300 {
        let mut f = s.frame(&t);
        // Pixel 0 always saturated; pixel 1 saturated in every third frame
        // with a wild clipped value that must not enter the statistics.
        f.saturated.data[0] = 1;
        f.dn.data[0] = 2047.0;
        if k % 3 == 0 {
            f.saturated.data[1] = 1;
            f.dn.data[1] = 2047.0;
        }
        acc.push(&f).unwrap();
    }
    let m = acc.moments().unwrap();
    let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
    assert_ne!(sep.flags.data[0] & flags::INSUFFICIENT, 0);
    assert_ne!(sep.flags.data[0] & flags::SATURATED, 0);
    assert_eq!(sep.i_plus_se_electrons.data[0], f32::INFINITY);
    assert_ne!(sep.flags.data[1] & flags::SATURATED, 0);
    assert_eq!(m.samples.data[1], 200.0);
    // Pixel 1's mean is unaffected by the clipped values.
    assert!(
        (m.mean_dn.data[1] - 104.0).abs() < 5.0,
        "{}",
        m.mean_dn.data[1]
    );
    assert_eq!(sep.flags.data[2], 0);
}

#[test]
fn variance_below_read_noise_is_clamped_and_flagged() {
    let h = SkellamMixing::new(0.05, 100.0);
    let mut acc = Welford::new(1, 1);
    for k in 0..10 {
        let mut f = Frame::new(1, 1);
        f.dn.data[0] = 10.0 + (k % 2) as f32; // variance ~0.28 << 100
        acc.push(&f).unwrap();
    }
    let sep = unmix(&acc.moments().unwrap(), &h, UnmixOptions::default()).unwrap();
    assert_ne!(sep.flags.data[0] & flags::VARIANCE_CLAMPED, 0);
    let (p, m) = (sep.i_plus_electrons.data[0], sep.i_minus_electrons.data[0]);
    assert!(p.is_finite() && m.is_finite());
    // Clamped: I+ + I- = 0, I+ - I- = mean / g.
    assert!((p + m).abs() < 1e-3 && ((p - m) - 10.5 / 0.05).abs() < 1e-2);
}

#[test]
fn one_frame_is_an_error_two_frames_are_defined() {
    let t = flat(3, 3, 100.0, 50.0);
    let mut s = Sampler::new(ti_h(), 5);
    let acc = m1(&mut s, &t, 1);
    assert_eq!(
        acc.moments().unwrap_err(),
        SeparationError::TooFewFrames { needed: 2, got: 1 }
    );
    assert!(Welford::new(3, 3).moments().is_err());
    let acc = m1(&mut s, &t, 2);
    let sep = unmix(&acc.moments().unwrap(), &ti_h(), UnmixOptions::default()).unwrap();
    assert!(all_finite(&sep.i_plus_electrons) && all_finite(&sep.i_minus_electrons));
    assert!(sep.i_plus_se_electrons.data.iter().all(|v| v.is_finite()));
}

#[test]
fn one_by_one_and_one_by_n_images() {
    let h = ti_h();
    let mut s = Sampler::new(h, 6);
    let one = flat(1, 1, 1000.0, 500.0);
    let f = s.frame(&one);
    for m in [
        bilateral_exact(&f, BilateralParams::new(2.0, 30.0)).unwrap(),
        bilateral_separable(&f, BilateralParams::new(2.0, 30.0)).unwrap(),
        bilateral_grid(&f, BilateralParams::new(2.0, 30.0)).unwrap(),
        segment_moments(&f, &Image::filled(1, 1, 0), None).unwrap(),
    ] {
        assert_ne!(m.flags.data[0] & flags::INSUFFICIENT, 0);
        let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
        assert!(all_finite(&sep.i_plus_electrons));
    }
    assert!(auto_segment(&f, SegmentParams::default()).is_ok());
    for (w, ht) in [(64, 1), (1, 64)] {
        let row = flat(w, ht, 1000.0, 500.0);
        let f = s.frame(&row);
        for m in [
            bilateral_exact(&f, BilateralParams::new(3.0, 1e9)).unwrap(),
            bilateral_separable(&f, BilateralParams::new(3.0, 1e9)).unwrap(),
            bilateral_grid(&f, BilateralParams::new(3.0, 1e9)).unwrap(),
            bilateral_grid(&f, BilateralParams::new(0.5, 30.0)).unwrap(),
            {
                let seg = auto_segment(&f, SegmentParams::default()).unwrap();
                segment_moments(&f, &seg.labels, Some(&seg.interior))
            }
            .unwrap(),
        ] {
            let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
            assert!(all_finite(&sep.i_plus_electrons) && all_finite(&sep.i_minus_electrons));
            assert!(m.flags.data.iter().all(|&f| f & flags::INSUFFICIENT == 0));
        }
    }
    // Empty frames are rejected.
    assert_eq!(
        bilateral_separable(&Frame::new(0, 0), BilateralParams::new(1.0, 1.0)).unwrap_err(),
        SeparationError::Empty
    );
    assert_eq!(
        bilateral_grid(&Frame::new(0, 0), BilateralParams::new(1.0, 1.0)).unwrap_err(),
        SeparationError::Empty
    );
}

#[test]
fn sigma_range_extremes_underflow_cleanly() {
    let h = ti_h();
    let t = chart(4, 3, 8, 4000.0);
    let f = Sampler::new(h, 7).frame(&t);
    for sr in [1e-300, 1e-6, 1e6, 1e300, f64::INFINITY] {
        for m in [
            bilateral_exact(&f, BilateralParams::new(2.0, sr)).unwrap(),
            bilateral_separable(&f, BilateralParams::new(2.0, sr)).unwrap(),
            bilateral_grid(&f, BilateralParams::new(2.0, sr)).unwrap(),
        ] {
            assert!(m.mean_dn.data.iter().all(|v| v.is_finite()), "sr {sr}");
            assert!(m.variance_dn2.data.iter().all(|v| v.is_finite()), "sr {sr}");
            let sep = unmix(&m, &h, UnmixOptions::default()).unwrap();
            assert!(all_finite(&sep.i_plus_electrons));
        }
    }
    // sigma_range -> 0: only equal values get weight; the mean is the pixel itself.
    let m = bilateral_exact(&f, BilateralParams::new(2.0, 1e-300)).unwrap();
    for i in 0..f.dn.len() {
        if m.flags.data[i] & flags::INSUFFICIENT == 0 {
            assert_eq!(m.mean_dn.data[i], f.dn.data[i] as f64);
        }
    }
    for bad in [0.0, -1.0, f64::NAN] {
        assert!(matches!(
            bilateral_separable(&f, BilateralParams::new(2.0, bad)),
            Err(SeparationError::Parameter { .. })
        ));
        assert!(matches!(
            bilateral_grid(&f, BilateralParams::new(2.0, bad)),
            Err(SeparationError::Parameter { .. })
        ));
    }
    assert!(bilateral_exact(&f, BilateralParams::new(f64::NAN, 1.0)).is_err());
}

#[test]
fn nan_and_inf_inputs_are_masked_never_spread() {
    let h = ti_h();
    let t = chart(4, 3, 8, 4000.0);
    let mut s = Sampler::new(h, 8);
    let poison = |f: &mut Frame| {
        f.dn.data[5] = f32::NAN;
        f.dn.data[40] = f32::INFINITY;
        f.dn.data[41] = f32::NEG_INFINITY;
    };
    let mut f = s.frame(&t);
    poison(&mut f);
    let labels = auto_segment(&f, SegmentParams::default()).unwrap();
    let mut acc = Welford::new(t.width, t.height);
    for _ in 0..5 {
        let mut g = s.frame(&t);
        poison(&mut g);
        acc.push(&g).unwrap();
    }
    for m in [
        bilateral_exact(&f, BilateralParams::new(2.0, 20.0)).unwrap(),
        bilateral_separable(&f, BilateralParams::new(2.0, 20.0)).unwrap(),
        bilateral_grid(&f, BilateralParams::new(2.0, 20.0)).unwrap(),
        segment_moments(&f, &labels.labels, Some(&labels.interior)).unwrap(),
        acc.moments().unwrap(),
    ] {
        for i in [5, 40, 41] {
            assert_ne!(m.flags.data[i] & flags::NONFINITE, 0);
        }
        for opts in [
            UnmixOptions::default(),
            UnmixOptions {
                nonnegative: true,
                ..Default::default()
            },
        ] {
            let sep = unmix(&m, &h, opts).unwrap();
            assert!(all_finite(&sep.i_plus_electrons) && all_finite(&sep.i_minus_electrons));
            assert!(sep.i_plus_se_electrons.data.iter().all(|v| !v.is_nan()));
        }
    }
    // A NaN or negative gain in H is rejected.
    let m = acc.moments().unwrap();
    assert!(unmix(
        &m,
        &SkellamMixing::new(f64::NAN, 1.0),
        UnmixOptions::default()
    )
    .is_err());
    assert!(unmix(&m, &SkellamMixing::new(0.0, 1.0), UnmixOptions::default()).is_err());
}
