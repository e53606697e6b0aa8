//! Physical parameters of a two-well ToF sensor, units in every name.

use serde::{Deserialize, Serialize};

use super::capture_range;
use super::skellam::SkellamMixing;

/// Everything the readout model D = rho * (eta * (N+ - N-) + n_read) needs
/// (eq. pixeleff, eq. skellamvar), plus the ADC and well limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorParams {
    /// Human-readable model name, e.g. "TI OPT8241".
    pub model: String,
    pub width: usize,
    pub height: usize,
    /// rho: DN per electron.
    pub conversion_gain_dn_per_electron: f64,
    /// eta in (0, 1]: demodulation contrast.
    pub demodulation_contrast: f64,
    /// sigma_read, referred to the well (electrons, before rho), counted once per readout.
    pub read_noise_electrons: f64,
    /// Capacity of each of the two wells.
    pub full_well_electrons: f64,
    /// ADC resolution; codes span [-2^(bits-1), 2^(bits-1) - 1].
    pub adc_bits: u32,
    /// Constant black level added before quantization, DN.
    pub adc_offset_dn: f64,
    /// Standard deviation of the per-pixel fixed-pattern offset, DN.
    pub fixed_pattern_sigma_dn: f64,
    /// Default exposure per frame.
    pub exposure_us: f64,
    /// Default frame rate.
    pub frame_rate_hz: f64,
    /// Default modulation (carrier) frequency of f(t).
    pub modulation_hz: f64,
}

/// A parameter outside its physical range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{name} = {} is out of range: expected {allowed}", crate::number::Number(*.value))]
pub struct ParamError {
    pub name: &'static str,
    pub value: f64,
    pub allowed: &'static str,
}

/// `Ok` when `ok` holds and `value` is finite, else the [`ParamError`]
/// naming the allowed range; shared by every parameter check in the crate.
pub(crate) fn check(
    name: &'static str,
    value: f64,
    ok: bool,
    allowed: &'static str,
) -> Result<(), ParamError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(ParamError {
            name,
            value,
            allowed,
        })
    }
}

impl SensorParams {
    /// Rejects NaN, infinities and non-physical values.
    pub fn validate(&self) -> Result<(), ParamError> {
        let p = self;
        check("width", p.width as f64, p.width > 0, "> 0")?;
        check("height", p.height as f64, p.height > 0, "> 0")?;
        let rho = p.conversion_gain_dn_per_electron;
        check("conversion_gain_dn_per_electron", rho, rho > 0.0, "> 0")?;
        let eta = p.demodulation_contrast;
        check(
            "demodulation_contrast",
            eta,
            eta > 0.0 && eta <= 1.0,
            "(0, 1]",
        )?;
        let r = p.read_noise_electrons;
        check("read_noise_electrons", r, r >= 0.0, ">= 0")?;
        let fw = p.full_well_electrons;
        check("full_well_electrons", fw, fw > 0.0, "> 0")?;
        let bits = p.adc_bits as f64;
        check("adc_bits", bits, (2..=24).contains(&p.adc_bits), "2..=24")?;
        check("adc_offset_dn", p.adc_offset_dn, true, "finite")?;
        let fp = p.fixed_pattern_sigma_dn;
        check("fixed_pattern_sigma_dn", fp, fp >= 0.0, ">= 0")?;
        // The capture settings: one range each, shared with sdid (capture_range).
        for (range, value) in [
            (capture_range::EXPOSURE_US, p.exposure_us),
            (capture_range::FRAME_RATE_HZ, p.frame_rate_hz),
            (capture_range::MODULATION_HZ, p.modulation_hz),
        ] {
            range.check(value).map_err(|e| ParamError {
                name: e.name,
                value,
                allowed: range.allowed,
            })?;
        }
        Ok(())
    }

    /// Lowest and highest ADC code.
    pub fn adc_range_dn(&self) -> (f64, f64) {
        let half = (1u64 << (self.adc_bits - 1)) as f64;
        (-half, half - 1.0)
    }

    /// rho * eta: DN per electron of well difference.
    pub fn gain_dn_per_electron(&self) -> f64 {
        self.conversion_gain_dn_per_electron * self.demodulation_contrast
    }

    /// Read-noise variance in DN^2: (rho * sigma_read)^2.
    pub fn read_variance_dn2(&self) -> f64 {
        let s = self.conversion_gain_dn_per_electron * self.read_noise_electrons;
        s * s
    }

    /// The Skellam mixing matrix H of these parameters, in DN (eq. skellammatrix).
    pub fn skellam(&self) -> SkellamMixing {
        SkellamMixing::new(self.gain_dn_per_electron(), self.read_variance_dn2())
    }
}
