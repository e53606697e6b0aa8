//! Skellam maximum likelihood: accuracy, optimality, extremes, non-negativity.

use proptest::prelude::*;
use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Poisson};
use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    skellam_log_likelihood, skellam_ml_counts, skellam_ml_pixel, MlMethod, SeparationError,
};

fn counts(p: f64, m: f64, n: usize, seed: u64) -> Vec<i64> {
    let mut rng = SmallRng::seed_from_u64(seed);
    let draw = |rng: &mut SmallRng, mu: f64| {
        if mu > 0.0 {
            Poisson::new(mu).unwrap().sample(rng) as i64
        } else {
            0
        }
    };
    (0..n)
        .map(|_| draw(&mut rng, p) - draw(&mut rng, m))
        .collect()
}

/// g = 1 DN/e-, read noise 0.1 e-: the counts regime.
fn low_read() -> SkellamMixing {
    SkellamMixing::new(1.0, 0.01)
}

#[test]
fn counts_regime_recovers_intensities_at_a_local_maximum() {
    let k = counts(50.0, 20.0, 4000, 1);
    let d: Vec<f64> = k.iter().map(|&v| v as f64 + 0.05).collect();
    let fit = skellam_ml_pixel(&d, &low_read()).unwrap();
    assert_eq!(fit.method, MlMethod::SkellamCounts);
    // Sampling sd of the sum ~ s sqrt(2/N) ~ 1.6 e-.
    eprintln!("ML: {fit:?}");
    assert!((fit.i_plus_electrons - 50.0).abs() < 5.0, "{fit:?}");
    assert!((fit.i_minus_electrons - 20.0).abs() < 5.0, "{fit:?}");
    // A maximum in both directions, not just along the I+ - I- = mean line.
    let (p, m) = (fit.i_plus_electrons, fit.i_minus_electrons);
    let l0 = skellam_log_likelihood(&k, p, m);
    for (dp, dm) in [(0.3, 0.0), (-0.3, 0.0), (0.0, 0.3), (0.0, -0.3), (0.3, 0.3)] {
        assert!(skellam_log_likelihood(&k, p + dp, m + dm) <= l0 + 1e-6);
    }
}

#[test]
fn extremes() {
    let h = low_read();
    // Zero photons.
    assert_eq!(skellam_ml_counts(&[0; 50]), (0.0, 0.0));
    // 1e7 electrons: no overflow; in this Gaussian limit the ML sum equals
    // the (1/N) sample variance, and truth is within its sampling error
    // (s sqrt(2/N) = 10% at N = 200).
    let k = counts(1e7, 5e6, 200, 2);
    let (p, m) = skellam_ml_counts(&k);
    let n = k.len() as f64;
    let mean = k.iter().sum::<i64>() as f64 / n;
    let var = k.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
    eprintln!("1e7: {p} {m}, sample variance {var}");
    assert!(p.is_finite() && m.is_finite());
    assert!(((p + m) / var - 1.0).abs() < 0.01, "{p} {m} {var}");
    assert!(((p + m) / 1.5e7 - 1.0).abs() < 0.3, "{p} {m}");
    // N = 1 and N = 2 in the counts regime: defined, non-negative.
    let f = skellam_ml_pixel(&[5.0], &h).unwrap();
    assert_eq!((f.i_plus_electrons, f.i_minus_electrons), (5.0, 0.0));
    let f = skellam_ml_pixel(&[-3.0, -5.0], &h).unwrap();
    assert!(f.i_plus_electrons >= 0.0 && f.i_minus_electrons >= 4.0);
    // NaN samples are skipped; nothing finite is an error.
    let f = skellam_ml_pixel(&[f64::NAN, 4.0, 6.0, f64::INFINITY], &h).unwrap();
    assert_eq!(f.samples, 2);
    assert_eq!(
        skellam_ml_pixel(&[f64::NAN], &h).unwrap_err(),
        SeparationError::TooFewFrames { needed: 1, got: 0 }
    );
    // The TI sensor's read noise (75 e-) is far above one electron: the
    // projected moments, which need two samples.
    let ti = SkellamMixing::new(0.08 * 0.65, 15.05);
    assert_eq!(
        skellam_ml_pixel(&[3.0], &ti).unwrap_err(),
        SeparationError::TooFewFrames { needed: 2, got: 1 }
    );
    let f = skellam_ml_pixel(&[3.0, -40.0, 12.0, 0.0], &ti).unwrap();
    assert_eq!(f.method, MlMethod::ProjectedMoments);
    assert!(f.i_plus_electrons >= 0.0 && f.i_minus_electrons >= 0.0);
    assert!(skellam_ml_pixel(&[1.0, 2.0], &SkellamMixing::new(f64::NAN, 1.0)).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn nonnegative_and_finite(k in prop::collection::vec(-200i64..200, 1..40)) {
        let (p, m) = skellam_ml_counts(&k);
        prop_assert!(p.is_finite() && m.is_finite() && p >= 0.0 && m >= 0.0);
        // I+ - I- equals the mean count.
        let mean = k.iter().sum::<i64>() as f64 / k.len() as f64;
        prop_assert!((p - m - mean).abs() <= 1e-6 * (1.0 + p + m));
    }
}
