//! Beyond the paper: per-pixel maximum likelihood of (I+, I-) from N frames,
//! non-negative by construction.
//!
//! Without read noise a pixel's electron difference k = N+ - N- is Skellam
//! distributed (eq. skellamvar): ln P(k) = (k/2) ln(I+/I-) - (sqrt I+ -
//! sqrt I-)^2 plus ln(I_|k|(2 sqrt(I+ I-)) e^-x), evaluated with the exponentially scaled
//! Bessel function ([`super::ln_bessel_i_scaled`]) so 1e7 electrons do not
//! overflow. The ML estimate satisfies I+ - I- = mean(k) (Karlis & Ntzoufras
//! 2006), so only the sum s = I+ + I- >= |mean k| is searched (golden
//! section on the log-likelihood, the boundary s = |mean k| being Poisson).
//!
//! The read noise convolves the Skellam with a Gaussian. Exact ML then needs a
//! sum over k per sample, so this module is honest about its regime:
//! - read noise below 0.5 electron ([`MlMethod::SkellamCounts`]): the counts
//!   are recovered as k = round(D / g) and the Skellam ML above is exact;
//! - otherwise ([`MlMethod::ProjectedMoments`]): the sum of two large Poisson
//!   counts plus Gaussian read noise is Gaussian to good approximation, whose
//!   ML under I+, I- >= 0 is the non-negative weighted least-squares
//!   projection of the moment estimate ([`super::unmix`] with `nonnegative`).

use super::{unmix, Moments, SeparationError, UnmixOptions};
use crate::sensor::{ParamError, SkellamMixing};

/// Which estimator produced a [`SkellamFit`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MlMethod {
    /// Exact Skellam ML on electron counts (read noise < 0.5 e-).
    SkellamCounts,
    /// Non-negative projection of the moments (Gaussian limit).
    ProjectedMoments,
}

/// Per-pixel ML estimate, electrons.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkellamFit {
    pub i_plus_electrons: f64,
    pub i_minus_electrons: f64,
    pub method: MlMethod,
    /// Finite samples used.
    pub samples: usize,
}

/// Read noise (electrons) below which counts are recovered by rounding.
pub const COUNTS_READ_NOISE_ELECTRONS: f64 = 0.5;

/// ML of (I+, I-) from one pixel's samples in DN (non-finite samples are
/// skipped). Errors: no finite sample, or a single one in the projected
/// regime (a variance needs two), an invalid H, or (counts regime) a
/// sample whose electron count does not fit an i64.
pub fn skellam_ml_pixel(
    samples_dn: &[f64],
    h: &SkellamMixing,
) -> Result<SkellamFit, SeparationError> {
    let g = h.gain_dn_per_electron;
    SeparationError::check("gain_dn_per_electron", g, g > 0.0, "> 0")?;
    let r = h.read_variance_dn2;
    SeparationError::check("read_variance_dn2", r, r >= 0.0, ">= 0")?;
    let xs: Vec<f64> = samples_dn
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let n = xs.len();
    if r.sqrt() / g < COUNTS_READ_NOISE_ELECTRONS {
        if n == 0 {
            return Err(SeparationError::TooFewFrames { needed: 1, got: 0 });
        }
        let mut k = Vec::with_capacity(n);
        for &d in &xs {
            let c = (d / g).round();
            // `as i64` would saturate silently: a count beyond i64 (a sample
            // over a tiny gain) is refused instead of being clipped.
            if c.abs() >= i64::MAX as f64 {
                return Err(SeparationError::Parameter(ParamError {
                    name: "sample_dn / gain_dn_per_electron",
                    value: c,
                    allowed: "an electron count within i64",
                }));
            }
            k.push(c as i64);
        }
        let (p, m) = skellam_ml_counts(&k);
        return Ok(SkellamFit {
            i_plus_electrons: p,
            i_minus_electrons: m,
            method: MlMethod::SkellamCounts,
            samples: n,
        });
    }
    if n < 2 {
        return Err(SeparationError::TooFewFrames { needed: 2, got: n });
    }
    let nf = n as f64;
    let mean = xs.iter().sum::<f64>() / nf;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (nf - 1.0);
    let mut mo = Moments::new(1, 1);
    mo.set_from_central(0, nf, mean, var, 0.0, None);
    let sep = unmix(
        &mo,
        h,
        UnmixOptions {
            subtract_read_noise: true,
            nonnegative: true,
        },
    )?;
    Ok(SkellamFit {
        i_plus_electrons: sep.i_plus_electrons.data[0] as f64,
        i_minus_electrons: sep.i_minus_electrons.data[0] as f64,
        method: MlMethod::ProjectedMoments,
        samples: n,
    })
}

/// Skellam log-likelihood of counts `k` at (mu1, mu2), both > 0.
pub fn skellam_log_likelihood(k: &[i64], mu1: f64, mu2: f64) -> f64 {
    let x = 2.0 * (mu1 * mu2).sqrt();
    let half_ln_ratio = 0.5 * (mu1.ln() - mu2.ln());
    let base = -(mu1.sqrt() - mu2.sqrt()).powi(2);
    k.iter()
        .map(|&ki| {
            ki as f64 * half_ln_ratio + base + super::ln_bessel_i_scaled(ki.unsigned_abs(), x)
        })
        .sum()
}

/// ln k! (exact sum below 30, Stirling series above).
fn ln_factorial(k: u64) -> f64 {
    if k < 30 {
        return (2..=k).map(|j| (j as f64).ln()).sum();
    }
    let x = k as f64 + 1.0;
    (x - 0.5) * x.ln() - x + 0.5 * (2.0 * std::f64::consts::PI).ln() + 1.0 / (12.0 * x)
        - 1.0 / (360.0 * x * x * x)
}

/// Poisson log-likelihood of counts that must all be >= 0 (the boundary
/// I- = 0, or I+ = 0 with the counts negated).
fn poisson_log_likelihood(k: &[i64], mu: f64) -> f64 {
    if k.iter().any(|&v| v < 0) {
        return f64::NEG_INFINITY;
    }
    if mu <= 0.0 {
        return if k.iter().all(|&v| v == 0) {
            0.0
        } else {
            f64::NEG_INFINITY
        };
    }
    k.iter()
        .map(|&v| v as f64 * mu.ln() - mu - ln_factorial(v as u64))
        .sum()
}

/// Skellam ML on counts: (I+, I-) >= 0 with I+ - I- = mean k.
pub fn skellam_ml_counts(k: &[i64]) -> (f64, f64) {
    if k.is_empty() {
        return (0.0, 0.0);
    }
    let n = k.len() as f64;
    let mean = k.iter().map(|&v| v as f64).sum::<f64>() / n;
    let d = mean.abs();
    let split = |s: f64| (0.5 * (s + mean), 0.5 * (s - mean));
    // Boundary: the smaller intensity is 0.
    let boundary = if mean >= 0.0 {
        poisson_log_likelihood(k, d)
    } else {
        // Saturating: -i64::MIN would overflow (it becomes i64::MAX, one count off).
        let neg: Vec<i64> = k.iter().map(|&v| v.saturating_neg()).collect();
        poisson_log_likelihood(&neg, d)
    };
    // Interior: golden section over s in (d, s_hi].
    let var = k.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
    let s_hi = 4.0 * var.max(d) + 10.0;
    let f = |s: f64| {
        let (p, m) = split(s);
        skellam_log_likelihood(k, p, m)
    };
    let (mut a, mut b) = (d + 1e-9 * (1.0 + d), s_hi);
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (b - phi * (b - a), a + phi * (b - a));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..100 {
        if (b - a) <= 1e-10 * (1.0 + b) {
            break;
        }
        if f1 < f2 {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + phi * (b - a);
            f2 = f(x2);
        } else {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - phi * (b - a);
            f1 = f(x1);
        }
    }
    let (s_best, f_best) = if f1 > f2 { (x1, f1) } else { (x2, f2) };
    if boundary >= f_best || !f_best.is_finite() {
        if mean >= 0.0 {
            (d, 0.0)
        } else {
            (0.0, d)
        }
    } else {
        let (p, m) = split(s_best);
        (p.max(0.0), m.max(0.0))
    }
}
