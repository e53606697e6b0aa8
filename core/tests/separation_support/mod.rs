//! Shared helpers for the separation tests: a patchwork test chart with known
//! I+ and I-, sampled with the paper's noise model (eq. skellamvar).
#![allow(dead_code)]

pub mod colour_chart;

use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, Poisson};
use sdi_core::sensor::SkellamMixing;
use sdi_core::{Frame, Image};

/// Ground truth of a test chart, electrons.
pub struct Truth {
    pub width: usize,
    pub height: usize,
    pub i_plus: Vec<f64>,
    pub i_minus: Vec<f64>,
}

/// A `cols` x `rows` chart of `patch` x `patch` pixel patches, each with its
/// own (I+, I-) between a few hundred and `scale` electrons.
pub fn chart(cols: usize, rows: usize, patch: usize, scale: f64) -> Truth {
    let (w, h) = (cols * patch, rows * patch);
    let mut i_plus = vec![0.0; w * h];
    let mut i_minus = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let k = (y / patch) * cols + x / patch;
            // Deterministic, well-spread levels (golden-ratio sequence).
            let a = ((k as f64 * 0.618_033_988_75).fract() * 0.85 + 0.15) * scale;
            let b = ((k as f64 * 0.414_213_562_37 + 0.3).fract() * 0.85 + 0.15) * scale;
            i_plus[y * w + x] = a;
            i_minus[y * w + x] = b;
        }
    }
    Truth {
        width: w,
        height: h,
        i_plus,
        i_minus,
    }
}

/// Samples frames: D = round(g (N+ - N-) + n_read), N+- Poisson, n_read ~ N(0, sigma_read^2 DN^2).
pub struct Sampler {
    pub h: SkellamMixing,
    rng: SmallRng,
}

impl Sampler {
    pub fn new(h: SkellamMixing, seed: u64) -> Self {
        Self {
            h,
            rng: SmallRng::seed_from_u64(seed),
        }
    }

    pub fn frame(&mut self, t: &Truth) -> Frame {
        let mut f = Frame::new(t.width, t.height);
        let read = Normal::new(0.0, self.h.read_variance_dn2.sqrt()).unwrap();
        for i in 0..t.width * t.height {
            let np = poisson(&mut self.rng, t.i_plus[i]);
            let nm = poisson(&mut self.rng, t.i_minus[i]);
            let d = self.h.gain_dn_per_electron * (np - nm) + read.sample(&mut self.rng);
            f.dn.data[i] = d.round() as f32;
        }
        f
    }
}

fn poisson(rng: &mut SmallRng, mean: f64) -> f64 {
    if mean <= 0.0 {
        return 0.0;
    }
    Poisson::new(mean).unwrap().sample(rng)
}

/// Relative RMSE and relative bias of an estimate over all pixels, against truth.
pub fn rel_rmse_bias(est: &Image<f32>, truth: &[f64]) -> (f64, f64) {
    let n = truth.len() as f64;
    let mean_t = truth.iter().sum::<f64>() / n;
    let errors = || est.data.iter().zip(truth).map(|(&e, t)| f64::from(e) - t);
    let rmse = (errors().map(|d| d * d).sum::<f64>() / n).sqrt();
    let bias = errors().sum::<f64>() / n;
    (rmse / mean_t, bias / mean_t)
}

/// The TI-like H used by most tests: g = 0.08 * 0.65, sigma_read^2 = 15.05 DN^2.
pub fn ti_h() -> SkellamMixing {
    SkellamMixing::new(0.08 * 0.65, 15.05)
}
