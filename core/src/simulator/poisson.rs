//! Exact Poisson sampling of one well's electron count (eq. poissonstats).
//!
//! Two regimes, both exact (no approximation of the distribution):
//! - mean < 10: sequential inversion of the CDF with one uniform draw; the
//!   expected number of steps is mean + 1.
//! - mean >= 10: PTRS, the transformed rejection method with squeeze of
//!   W. Hörmann, "The transformed rejection method for generating Poisson
//!   random variables", Insurance: Mathematics and Economics 12 (1993). About
//!   1.1 iterations per sample on average, most of them accepted by the
//!   squeeze without evaluating a logarithm.
//!
//! The simulator only uses this path where the per-well counts matter
//! (few electrons, wells near full-well capacity, coarse gain); bright
//! unsaturated pixels take the moment-matched Gaussian in `readout`.
//!
//! By hand rather than `rand_distr::Poisson`: that one returns f64 and its
//! sample sequence may change between releases, while the simulator's
//! seeded scenes and statistical tests need a fixed, exact u64 sampler.

use rand::Rng;

/// Below this mean the sampler inverts the CDF; from it on it uses PTRS
/// (whose constants are fitted for means >= 10).
pub const INVERSION_LIMIT: f64 = 10.0;

/// ln(k!) for k < 10, exact to f64 precision.
const LN_FACTORIAL_SMALL: [f64; 10] = [
    0.0,
    0.0,
    std::f64::consts::LN_2,
    1.791_759_469_228_055,
    3.178_053_830_347_945_8,
    4.787_491_742_782_046,
    6.579_251_212_010_101,
    8.525_161_361_065_415,
    10.604_602_902_745_25,
    12.801_827_480_081_469,
];

/// ln(k!): table below 10, Stirling's series above (error < 1e-12 for k >= 10).
pub fn ln_factorial(k: u64) -> f64 {
    if k < 10 {
        return LN_FACTORIAL_SMALL[k as usize];
    }
    let n = k as f64;
    let r = 1.0 / n;
    let r2 = r * r;
    n * n.ln() - n
        + 0.5 * (std::f64::consts::TAU * n).ln()
        + r * (1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0)))
}

/// A Poisson distribution of fixed mean with its set-up constants computed once.
#[derive(Debug, Clone, Copy)]
pub struct PoissonSampler {
    mean: f64,
    kind: Kind,
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    /// Mean 0 (or not a positive finite number): always 0.
    Zero,
    /// exp(-mean).
    Inversion {
        p0: f64,
    },
    Ptrs(Ptrs),
}

/// Hörmann's PTRS constants for one mean.
#[derive(Debug, Clone, Copy)]
struct Ptrs {
    ln_mean: f64,
    a: f64,
    b: f64,
    ln_inv_alpha: f64,
    v_r: f64,
}

impl PoissonSampler {
    /// A sampler of mean `mean` electrons; non-positive or non-finite means
    /// give a sampler that always returns 0.
    pub fn new(mean: f64) -> Self {
        let kind = if !(mean > 0.0 && mean.is_finite()) {
            Kind::Zero
        } else if mean < INVERSION_LIMIT {
            Kind::Inversion { p0: (-mean).exp() }
        } else {
            let s = mean.sqrt();
            let b = 0.931 + 2.53 * s;
            let a = -0.059 + 0.024_83 * b;
            let inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
            Kind::Ptrs(Ptrs {
                ln_mean: mean.ln(),
                a,
                b,
                ln_inv_alpha: inv_alpha.ln(),
                v_r: 0.9277 - 3.6224 / (b - 2.0),
            })
        };
        Self { mean, kind }
    }

    pub fn mean(&self) -> f64 {
        self.mean
    }

    /// One draw, as a count of electrons.
    #[inline]
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> u64 {
        match self.kind {
            Kind::Zero => 0,
            Kind::Inversion { p0 } => self.invert(p0, rng),
            Kind::Ptrs(c) => self.ptrs(&c, rng),
        }
    }

    fn invert<R: Rng + ?Sized>(&self, p0: f64, rng: &mut R) -> u64 {
        let u: f64 = rng.random();
        let (mut k, mut p, mut cdf) = (0u64, p0, p0);
        // The tail beyond 200 has probability < 1e-150 for mean < 10; the cap
        // only guards against the CDF rounding to just below 1.
        while u > cdf && k < 200 {
            k += 1;
            p *= self.mean / k as f64;
            cdf += p;
        }
        k
    }

    fn ptrs<R: Rng + ?Sized>(&self, c: &Ptrs, rng: &mut R) -> u64 {
        loop {
            let u = rng.random::<f64>() - 0.5;
            let v: f64 = rng.random();
            let us = 0.5 - u.abs();
            let k = ((2.0 * c.a / us + c.b) * u + self.mean + 0.43).floor();
            // Squeeze: the bulk of draws is accepted here.
            if us >= 0.07 && v <= c.v_r {
                return k as u64;
            }
            if k < 0.0 || (us < 0.013 && v > us) {
                continue;
            }
            let lhs = v.ln() + c.ln_inv_alpha - (c.a / (us * us) + c.b).ln();
            let rhs = -self.mean + k * c.ln_mean - ln_factorial(k as u64);
            if lhs <= rhs {
                return k as u64;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::SeedableRng;

    #[test]
    fn ln_factorial_matches_direct_sum() {
        let mut acc = 0.0f64;
        for k in 1..200u64 {
            acc += (k as f64).ln();
            assert!((ln_factorial(k) - acc).abs() < 1e-9 * acc.max(1.0), "k={k}");
        }
    }

    /// Sample mean within 5 standard errors and sample variance within 5
    /// standard errors of its own estimator (var of s^2 ~ (mu4 - s^4 (n-3)/(n-1)) / n,
    /// mu4 = 3 m^2 + m for a Poisson of mean m).
    #[test]
    fn mean_and_variance_match_across_regimes() {
        let mut rng = SmallRng::seed_from_u64(7);
        for &m in &[0.3, 2.0, 9.99, 10.0, 37.5, 400.0, 40_000.0] {
            let s = PoissonSampler::new(m);
            let n = 200_000usize;
            let xs: Vec<f64> = (0..n).map(|_| s.sample(&mut rng) as f64).collect();
            let mean = xs.iter().sum::<f64>() / n as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let se_mean = (m / n as f64).sqrt();
            let mu4 = 3.0 * m * m + m;
            let se_var = ((mu4 - m * m * (n as f64 - 3.0) / (n as f64 - 1.0)) / n as f64).sqrt();
            assert!((mean - m).abs() < 5.0 * se_mean, "m={m} mean={mean}");
            assert!((var - m).abs() < 5.0 * se_var, "m={m} var={var}");
        }
    }

    #[test]
    fn small_mean_probabilities_match_pmf() {
        let mut rng = SmallRng::seed_from_u64(3);
        let m = 1.5;
        let s = PoissonSampler::new(m);
        let n = 400_000;
        let mut hist = [0usize; 8];
        for _ in 0..n {
            let k = s.sample(&mut rng) as usize;
            if k < hist.len() {
                hist[k] += 1;
            }
        }
        for (k, &c) in hist.iter().enumerate() {
            let p = (-m + k as f64 * m.ln() - ln_factorial(k as u64)).exp();
            let se = (p * (1.0 - p) / n as f64).sqrt();
            assert!((c as f64 / n as f64 - p).abs() < 5.0 * se + 1e-6, "k={k}");
        }
    }

    #[test]
    fn degenerate_means_give_zero() {
        let mut rng = SmallRng::seed_from_u64(1);
        for m in [0.0, -3.0, f64::NAN, f64::INFINITY] {
            assert_eq!(PoissonSampler::new(m).sample(&mut rng), 0);
        }
    }
}
