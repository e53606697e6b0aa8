//! Sensor description files (TOML): every figure of the readout model
//! D = rho * (eta * (N+ - N-) + n_read) (eq. pixeleff, eq. skellamvar) in one
//! user-editable file. The presets `ti` and `pmd` ship as such files
//! (`core/sensors/*.toml`, embedded); a test keeps them equal to
//! [`SensorPreset::params`].
//!
//! H built from a description ([`mixing_with_adc`]) counts the ADC's rounding
//! variance, 1/12 DN^2 per readout (Sheppard's correction, valid while the
//! read noise spans more than about one code), in its read term; a measured
//! calibration already contains it.

use serde::{Deserialize, Serialize};

use super::{ParamError, SensorParams, SensorPreset, SkellamMixing};

/// Variance a rounding ADC adds per readout, DN^2 (uniform over one code).
pub const ADC_ROUNDING_VARIANCE_DN2: f64 = 1.0 / 12.0;

/// Smallest demodulation contrast accepted: below it H (det H = 2 rho^3 eta^3,
/// eq. skellammatrix) is so ill-conditioned that I+ and I- are not recoverable
/// in f32.
pub const MIN_DEMODULATION_CONTRAST: f64 = 1e-6;

/// The TI OPT8241 preset as shipped.
pub const TI_TOML: &str = include_str!("../../sensors/ti.toml");
/// The PMD CamBoard nano preset as shipped.
pub const PMD_TOML: &str = include_str!("../../sensors/pmd.toml");

/// A sensor description file. Units are in the names; unknown keys are refused
/// so a misspelt key cannot silently fall back to a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorDescription {
    pub model: String,
    pub width: usize,
    pub height: usize,
    /// rho, DN per electron.
    pub conversion_gain_dn_per_electron: f64,
    /// eta in [1e-6, 1].
    pub demodulation_contrast: f64,
    /// sigma_read referred to the well, electrons, once per readout.
    pub read_noise_electrons: f64,
    pub full_well_electrons: f64,
    pub adc_bits: u32,
    #[serde(default)]
    pub adc_offset_dn: f64,
    /// Per-pixel fixed-pattern offset (standard deviation), DN.
    #[serde(default)]
    pub fixed_pattern_sigma_dn: f64,
    /// Dark current, electrons per microsecond per well. The simulator adds it
    /// like uncorrelated light (both wells, shot noise included).
    #[serde(default)]
    pub dark_current_electrons_per_us: f64,
    pub exposure_us: f64,
    pub frame_rate_hz: f64,
    /// Default modulation frequency, and the range the sensor accepts.
    pub modulation_hz: f64,
    #[serde(default)]
    pub min_modulation_hz: Option<f64>,
    #[serde(default)]
    pub max_modulation_hz: Option<f64>,
}

/// Why a description cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum DescriptionError {
    #[error("sensor description: {0}")]
    Toml(#[from] toml::de::Error),
    #[error("sensor description: {0}")]
    Param(#[from] ParamError),
}

impl SensorDescription {
    /// Parses and validates a TOML description.
    pub fn from_toml(text: &str) -> Result<Self, DescriptionError> {
        let d: Self = toml::from_str(text)?;
        d.validate()?;
        Ok(d)
    }

    /// TOML text of this description.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// The description of a built-in preset.
    pub fn preset(p: SensorPreset) -> Self {
        let p = p.params();
        Self {
            model: p.model,
            width: p.width,
            height: p.height,
            conversion_gain_dn_per_electron: p.conversion_gain_dn_per_electron,
            demodulation_contrast: p.demodulation_contrast,
            read_noise_electrons: p.read_noise_electrons,
            full_well_electrons: p.full_well_electrons,
            adc_bits: p.adc_bits,
            adc_offset_dn: p.adc_offset_dn,
            fixed_pattern_sigma_dn: p.fixed_pattern_sigma_dn,
            dark_current_electrons_per_us: 0.0,
            exposure_us: p.exposure_us,
            frame_rate_hz: p.frame_rate_hz,
            modulation_hz: p.modulation_hz,
            min_modulation_hz: None,
            max_modulation_hz: None,
        }
    }

    /// Everything [`SensorParams::validate`] checks, plus eta >= 1e-6, a
    /// frame of at most 2^24 pixels, dark current >= 0 and the modulation
    /// limits (positive, ordered, containing the default).
    pub fn validate(&self) -> Result<(), ParamError> {
        self.params().validate()?;
        let eta = self.demodulation_contrast;
        super::check(
            "demodulation_contrast",
            eta,
            eta >= MIN_DEMODULATION_CONTRAST,
            ">= 1e-6 (H is singular below)",
        )?;
        let px = self.width as f64 * self.height as f64;
        super::check("width * height", px, px <= 16_777_216.0, "<= 2^24 pixels")?;
        let dc = self.dark_current_electrons_per_us;
        super::check("dark_current_electrons_per_us", dc, dc >= 0.0, ">= 0")?;
        let lo = self.min_modulation_hz.unwrap_or(0.0);
        let hi = self.max_modulation_hz.unwrap_or(f64::MAX);
        super::check("min_modulation_hz", lo, lo >= 0.0, ">= 0")?;
        super::check("max_modulation_hz", hi, hi >= lo, ">= min_modulation_hz")?;
        let m = self.modulation_hz;
        super::check(
            "modulation_hz",
            m,
            (lo..=hi).contains(&m),
            "within [min_modulation_hz, max_modulation_hz]",
        )?;
        Ok(())
    }

    /// The simulator's and separation's parameters.
    pub fn params(&self) -> SensorParams {
        SensorParams {
            model: self.model.clone(),
            width: self.width,
            height: self.height,
            conversion_gain_dn_per_electron: self.conversion_gain_dn_per_electron,
            demodulation_contrast: self.demodulation_contrast,
            read_noise_electrons: self.read_noise_electrons,
            full_well_electrons: self.full_well_electrons,
            adc_bits: self.adc_bits,
            adc_offset_dn: self.adc_offset_dn,
            fixed_pattern_sigma_dn: self.fixed_pattern_sigma_dn,
            exposure_us: self.exposure_us,
            frame_rate_hz: self.frame_rate_hz,
            modulation_hz: self.modulation_hz,
        }
    }

    /// Refuses a modulation frequency outside the sensor's limits.
    pub fn check_modulation_hz(&self, hz: f64) -> Result<(), ParamError> {
        let lo = self.min_modulation_hz.unwrap_or(0.0);
        let hi = self.max_modulation_hz.unwrap_or(f64::MAX);
        super::check(
            "modulation_hz",
            hz,
            hz > 0.0 && (lo..=hi).contains(&hz),
            "within the sensor's [min_modulation_hz, max_modulation_hz]",
        )
    }
}

/// H of a sensor description with the ADC's rounding in the read term:
/// (mu, sigma^2 - sigma_read^2 - 1/12) = H (I+, I-) (eq. skellammatrix).
/// [`SensorParams::skellam`] leaves the rounding out.
pub fn mixing_with_adc(p: &SensorParams) -> SkellamMixing {
    SkellamMixing::new(
        p.gain_dn_per_electron(),
        p.read_variance_dn2() + ADC_ROUNDING_VARIANCE_DN2,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_files_equal_the_presets() {
        for (text, preset) in [
            (TI_TOML, SensorPreset::TiOpt8241),
            (PMD_TOML, SensorPreset::PmdCamBoardNano),
        ] {
            let d = SensorDescription::from_toml(text).unwrap();
            let p = d.params();
            let q = preset.params();
            assert_eq!(p.model, q.model);
            assert_eq!(
                (p.width, p.height, p.adc_bits),
                (q.width, q.height, q.adc_bits)
            );
            for (a, b) in [
                (
                    p.conversion_gain_dn_per_electron,
                    q.conversion_gain_dn_per_electron,
                ),
                (p.demodulation_contrast, q.demodulation_contrast),
                (p.read_variance_dn2(), q.read_variance_dn2()),
                (p.full_well_electrons, q.full_well_electrons),
                (p.fixed_pattern_sigma_dn, q.fixed_pattern_sigma_dn),
                (p.exposure_us, q.exposure_us),
                (p.frame_rate_hz, q.frame_rate_hz),
                (p.modulation_hz, q.modulation_hz),
            ] {
                assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} vs {b}");
            }
        }
    }

    #[test]
    fn bad_descriptions_are_refused_with_the_field_named() {
        let base = SensorDescription::preset(SensorPreset::TiOpt8241);
        type Edit = Box<dyn Fn(&mut SensorDescription)>;
        let cases: [(&str, Edit); 7] = [
            (
                "demodulation_contrast",
                Box::new(|d| d.demodulation_contrast = 0.0),
            ),
            (
                "demodulation_contrast",
                Box::new(|d| d.demodulation_contrast = 1e-12),
            ),
            (
                "conversion_gain",
                Box::new(|d| d.conversion_gain_dn_per_electron = 0.0),
            ),
            ("read_noise", Box::new(|d| d.read_noise_electrons = -1.0)),
            ("width", Box::new(|d| d.width = 0)),
            ("full_well", Box::new(|d| d.full_well_electrons = f64::NAN)),
            (
                "modulation_hz",
                Box::new(|d| d.max_modulation_hz = Some(0.5e6)),
            ),
        ];
        for (field, edit) in cases {
            let mut d = base.clone();
            edit(&mut d);
            let text = d.to_toml();
            let err = SensorDescription::from_toml(&text)
                .map(|_| ())
                .map_err(|e| e.to_string());
            match err {
                Err(e) => assert!(e.contains(field), "{field}: {e}"),
                // NaN does not survive TOML; the parse error is enough.
                Ok(()) => panic!("{field} accepted"),
            }
        }
        assert!(SensorDescription::from_toml("model = 'x'\nbogus = 1").is_err());
    }

    #[test]
    fn rounding_is_in_the_read_term() {
        let p = SensorPreset::TiOpt8241.params();
        let h = mixing_with_adc(&p);
        assert!((h.read_variance_dn2 - 15.05 - 1.0 / 12.0).abs() < 1e-9);
    }
}
