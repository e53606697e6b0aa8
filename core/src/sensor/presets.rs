//! Documented sensor presets.
//!
//! Read-noise figures are fitted to the paper's section 5.5: the lowest
//! (extrapolated) single-readout variance was 15.05 DN^2 for the TI sensor and
//! 127.90 DN^2 for the PMD sensor, so rho * sigma_read = sqrt of those. The
//! remaining values (rho, eta, full well) are typical for the parts and chosen
//! so that one full well of difference spans the ADC; the calibration module
//! replaces them with measured values.

use super::SensorParams;

crate::named_enum! {
    /// Named presets: "ti" and "pmd" on command lines and in config files.
    pub enum SensorPreset {
        /// TI OPT8241 (320x240, 12-bit signed A-B output).
        #[strum(serialize = "ti")]
        TiOpt8241,
        /// PMD CamBoard nano (165x120).
        #[strum(serialize = "pmd")]
        PmdCamBoardNano,
    }
}

impl SensorPreset {
    pub fn from_name(name: &str) -> Option<Self> {
        name.parse().ok()
    }

    /// The preset's sensor description file as shipped (`core/sensors/`).
    pub fn toml(self) -> &'static str {
        match self {
            SensorPreset::TiOpt8241 => super::description::TI_TOML,
            SensorPreset::PmdCamBoardNano => super::description::PMD_TOML,
        }
    }

    pub fn params(self) -> SensorParams {
        match self {
            SensorPreset::TiOpt8241 => {
                let rho = 0.08;
                SensorParams {
                    model: "TI OPT8241".into(),
                    width: 320,
                    height: 240,
                    conversion_gain_dn_per_electron: rho,
                    demodulation_contrast: 0.65,
                    read_noise_electrons: 15.05f64.sqrt() / rho,
                    full_well_electrons: 40_000.0,
                    adc_bits: 12,
                    adc_offset_dn: 0.0,
                    fixed_pattern_sigma_dn: 4.0,
                    exposure_us: 2000.0,
                    frame_rate_hz: 60.0,
                    // The paper's prototype: an external generator at 1-5 MHz
                    // (section 3), where light travel is negligible; the
                    // board's own PLL starts near 9.4 MHz (its backend's limits).
                    modulation_hz: 1e6,
                }
            }
            SensorPreset::PmdCamBoardNano => {
                let rho = 0.5;
                SensorParams {
                    model: "PMD CamBoard nano".into(),
                    width: 165,
                    height: 120,
                    conversion_gain_dn_per_electron: rho,
                    demodulation_contrast: 0.4,
                    read_noise_electrons: 127.90f64.sqrt() / rho,
                    full_well_electrons: 20_000.0,
                    adc_bits: 14,
                    adc_offset_dn: 0.0,
                    fixed_pattern_sigma_dn: 8.0,
                    exposure_us: 2000.0,
                    frame_rate_hz: 60.0,
                    modulation_hz: 2e6,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_match_paper_read_noise() {
        for p in <SensorPreset as strum::IntoEnumIterator>::iter() {
            p.params().validate().unwrap();
        }
        assert_eq!(SensorPreset::NAMES, ["ti", "pmd"]);
        let ti = SensorPreset::TiOpt8241.params();
        assert!((ti.read_variance_dn2() - 15.05).abs() < 1e-9);
        let pmd = SensorPreset::PmdCamBoardNano.params();
        assert!((pmd.read_variance_dn2() - 127.90).abs() < 1e-9);
    }
}
