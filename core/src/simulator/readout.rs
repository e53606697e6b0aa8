//! From expected well contents to ADC codes: shot noise, full well, read
//! noise, fixed-pattern offset and the ADC (eq. pixeleff, eq. skellamvar).
//!
//! Per pixel the exact model is
//! D = rho * (eta * (N+ - N-) + n_read) + offset + fpn,
//! N+- ~ Poisson(I+-) clipped at full well, n_read ~ Normal(0, sigma_read^2),
//! then rounding and clipping to the ADC's code range.
//!
//! Sampling that literally costs two Poisson draws and one Gaussian draw per
//! pixel. Where it cannot change the result, a pixel instead takes one draw of
//! a moment-matched continuous variable (the *Gaussian path*):
//! - the wells expect together at least [`GAUSSIAN_MIN_ELECTRONS`] electrons
//!   (or none at all, where D is exactly Gaussian read noise);
//! - neither well comes within 7 standard deviations of full well, so
//!   saturation has probability < 1e-11 and the individual counts are not
//!   needed;
//! - one electron of difference is at most [`GAUSSIAN_MAX_GAIN_DN`] DN, so the
//!   integer lattice of N+ - N- is finer than the ADC's code step and is not
//!   visible after quantization.
//!
//! The Gaussian path reproduces mean, variance *and* skewness of D: with
//! g = rho * eta, mean g (I+ - I-), variance g^2 (I+ + I-) + (rho sigma_read)^2
//! (eq. skellamvar) and third cumulant g^3 (I+ - I-) (Skellam), through the
//! first Cornish-Fisher term y = mu + sigma (z + gamma/6 (z^2 - 1)). The error
//! left is the Skellam's excess kurtosis, 1 / (I+ + I-) <= 1 % at the
//! threshold. All other pixels take the exact path with [`PoissonSampler`].

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use super::poisson::PoissonSampler;
use crate::frame::Frame;
use crate::image::Image;
use crate::sensor::SensorParams;

/// Fewest expected electrons (I+ + I-) for the Gaussian path.
pub const GAUSSIAN_MIN_ELECTRONS: f64 = 100.0;
/// Largest rho * eta (DN per electron of difference) for the Gaussian path.
pub const GAUSSIAN_MAX_GAIN_DN: f64 = 0.25;
/// Distance from full well, in standard deviations of a well, below which a
/// pixel is sampled per well so saturation is modelled exactly.
const SATURATION_MARGIN_SIGMA: f64 = 7.0;

/// The ADC: rounds to integer codes and clips to the code range.
#[derive(Debug, Clone, Copy)]
pub struct Adc {
    lo_dn: f64,
    hi_dn: f64,
    offset_dn: f64,
}

impl Adc {
    pub fn new(params: &SensorParams) -> Self {
        let (lo_dn, hi_dn) = params.adc_range_dn();
        Self {
            lo_dn,
            hi_dn,
            offset_dn: params.adc_offset_dn,
        }
    }

    /// Quantizes an analog value (DN, offset and fixed pattern included) to a
    /// code; returns (code minus the black-level offset, clipped).
    #[inline]
    pub fn convert(&self, analog_dn: f64) -> (f32, bool) {
        // Clamp first so the integer conversion below stays in range (and NaN
        // cannot occur: inputs are finite by construction).
        let a = analog_dn.clamp(self.lo_dn - 1.0, self.hi_dn + 1.0);
        // Round half up without a libm call: shift positive, truncate.
        const SHIFT: f64 = 16_777_216.0;
        let code = ((a + 0.5 + SHIFT) as i64) as f64 - SHIFT;
        let clipped = code < self.lo_dn || code > self.hi_dn;
        let code = code.clamp(self.lo_dn, self.hi_dn);
        ((code - self.offset_dn) as f32, clipped)
    }
}

/// Per-pixel precomputed readout for one set of expected well contents.
#[derive(Debug, Clone, Copy, Default)]
struct PixelPlan {
    /// Mean analog value, DN: g (I+ - I-) + offset + fpn (Gaussian path) or
    /// offset + fpn (exact path).
    base_dn: f32,
    /// Standard deviation, DN; negative marks the exact path.
    sd_dn: f32,
    /// gamma / 6, the Cornish-Fisher skewness coefficient.
    skew: f32,
}

/// A pixel sampled per well.
#[derive(Debug, Clone, Copy)]
struct ExactPixel {
    index: usize,
    plus: PoissonSampler,
    minus: PoissonSampler,
}

/// Everything the per-frame sampling loop needs, computed once per
/// expectation (and reused across frames of a static scene).
#[derive(Debug, Clone, Default)]
pub struct ReadoutPlan {
    pixels: Vec<PixelPlan>,
    exact: Vec<ExactPixel>,
}

impl ReadoutPlan {
    /// Number of pixels that take the exact per-well path.
    pub fn exact_count(&self) -> usize {
        self.exact.len()
    }

    /// Rebuilds the plan in place for expected well contents (electrons) and
    /// a fixed-pattern offset image (DN).
    pub fn rebuild(
        &mut self,
        params: &SensorParams,
        i_plus_electrons: &[f32],
        i_minus_electrons: &[f32],
        fixed_pattern_dn: &[f32],
    ) {
        let n = i_plus_electrons.len();
        self.pixels.clear();
        self.pixels.reserve(n);
        self.exact.clear();
        let g = params.gain_dn_per_electron();
        let read_var_dn2 = params.read_variance_dn2();
        let full_well = params.full_well_electrons;
        let offset = params.adc_offset_dn;
        let coarse = g > GAUSSIAN_MAX_GAIN_DN;
        let near_full = |m: f64| m + SATURATION_MARGIN_SIGMA * m.sqrt() + 1.0 >= full_well;
        for (index, ((&p, &m), &fpn)) in i_plus_electrons
            .iter()
            .zip(i_minus_electrons)
            .zip(fixed_pattern_dn)
            .enumerate()
        {
            let (p, m) = ((p as f64).max(0.0), (m as f64).max(0.0));
            let total = p + m;
            let base = offset + fpn as f64;
            let gaussian = total == 0.0
                || (total >= GAUSSIAN_MIN_ELECTRONS && !coarse && !near_full(p) && !near_full(m));
            if gaussian {
                let var = g * g * total + read_var_dn2;
                let sd = var.sqrt();
                let k3 = g * g * g * (p - m);
                let skew = if var > 0.0 {
                    k3 / (6.0 * var * sd)
                } else {
                    0.0
                };
                self.pixels.push(PixelPlan {
                    base_dn: (base + g * (p - m)) as f32,
                    sd_dn: sd as f32,
                    skew: skew as f32,
                });
            } else {
                self.pixels.push(PixelPlan {
                    base_dn: base as f32,
                    sd_dn: -1.0,
                    skew: 0.0,
                });
                self.exact.push(ExactPixel {
                    index,
                    plus: PoissonSampler::new(p),
                    minus: PoissonSampler::new(m),
                });
            }
        }
    }

    /// Samples one frame into `out` (codes minus offset, saturation flags).
    pub fn sample<R: Rng>(&self, params: &SensorParams, rng: &mut R, out: &mut Frame) {
        let adc = Adc::new(params);
        let dn = &mut out.dn.data;
        let sat = &mut out.saturated.data;
        for ((plan, d), s) in self.pixels.iter().zip(dn.iter_mut()).zip(sat.iter_mut()) {
            if plan.sd_dn < 0.0 {
                continue;
            }
            let z: f64 = StandardNormal.sample(rng);
            let y =
                plan.base_dn as f64 + plan.sd_dn as f64 * (z + plan.skew as f64 * (z * z - 1.0));
            let (code, clipped) = adc.convert(y);
            *d = code;
            *s = u8::from(clipped);
        }
        let rho = params.conversion_gain_dn_per_electron;
        let eta = params.demodulation_contrast;
        let read_e = params.read_noise_electrons;
        let full_well = params.full_well_electrons.floor();
        for e in &self.exact {
            let np = (e.plus.sample(rng) as f64).min(full_well);
            let nm = (e.minus.sample(rng) as f64).min(full_well);
            let well_full = np >= full_well || nm >= full_well;
            let z: f64 = StandardNormal.sample(rng);
            let analog = rho * (eta * (np - nm) + read_e * z) + self.pixels[e.index].base_dn as f64;
            let (code, clipped) = adc.convert(analog);
            dn[e.index] = code;
            sat[e.index] = u8::from(well_full || clipped);
        }
    }
}

/// The reference readout: literally two `rand_distr::Poisson` draws and one
/// Gaussian draw per pixel, no plan. Kept to cross-check and benchmark the
/// fast path against.
pub fn sample_reference<R: Rng>(
    params: &SensorParams,
    i_plus_electrons: &Image<f32>,
    i_minus_electrons: &Image<f32>,
    fixed_pattern_dn: &Image<f32>,
    rng: &mut R,
    out: &mut Frame,
) {
    let adc = Adc::new(params);
    let rho = params.conversion_gain_dn_per_electron;
    let eta = params.demodulation_contrast;
    let full_well = params.full_well_electrons.floor();
    let read = rand_distr::Normal::new(0.0, params.read_noise_electrons).ok();
    let poisson = |rng: &mut R, mean: f32| -> f64 {
        match rand_distr::Poisson::new(mean as f64) {
            Ok(d) => d.sample(rng),
            Err(_) => 0.0,
        }
    };
    for i in 0..out.dn.data.len() {
        let np = poisson(rng, i_plus_electrons.data[i]).min(full_well);
        let nm = poisson(rng, i_minus_electrons.data[i]).min(full_well);
        let well_full = np >= full_well || nm >= full_well;
        let n_read = read.map_or(0.0, |n| n.sample(rng));
        let analog = rho * (eta * (np - nm) + n_read)
            + params.adc_offset_dn
            + fixed_pattern_dn.data[i] as f64;
        let (code, clipped) = adc.convert(analog);
        out.dn.data[i] = code;
        out.saturated.data[i] = u8::from(well_full || clipped);
    }
}
