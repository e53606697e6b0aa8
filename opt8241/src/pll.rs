//! The modulation PLL: the modulation frequencies it reaches, and which m,
//! fraction and prescaler give one, as the SDK computes them.

use crate::range::{OutOfRange, Range};
use crate::registers::SYSTEM_CLOCK_HZ;

/// VCO range of the modulation PLL (OPT9221.dml, mod_m1 description).
pub const VCO_MIN_HZ: f64 = 300e6;
pub const VCO_MAX_HZ: f64 = 600e6;
/// Largest mod_ps1 (3-bit field).
pub const MOD_PS_MAX: u32 = 7;
/// mod_n1 as the SDK sets it (`TintinVCOFrequency::set`).
pub const MOD_N: u32 = 2;

/// Modulation PLL settings: f_mod = VCO / (quads * (1 + ps)),
/// VCO = 2 * f_sys * (m + frac / 2^16) / 2^n (OPT9221.dml; SDK
/// `TintinVCOFrequency`, `TintinModulationFrequencyParameter`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PllSettings {
    pub m: u32,
    pub m_frac: u32,
    pub n: u32,
    pub ps: u32,
    /// What the settings really give.
    pub modulation_hz: f64,
    pub vco_hz: f64,
}

impl PllSettings {
    /// The SDK's choice: the largest prescaler keeping the VCO above its
    /// minimum, then m and its fraction.
    pub fn for_modulation(modulation_hz: f64, quads: u32) -> Result<Self, OutOfRange> {
        modulation_range_hz(quads).check(modulation_hz)?;
        let q = quads as f64;
        let ps = ((VCO_MIN_HZ / q / modulation_hz).floor() as u32).min(MOD_PS_MAX);
        let vco_hz = (ps + 1) as f64 * q * modulation_hz;
        let mf = vco_hz * (1u32 << MOD_N) as f64 / (2.0 * SYSTEM_CLOCK_HZ);
        let m = mf.floor() as u32;
        let m_frac = ((mf - m as f64) * 65536.0).floor() as u32;
        let vco_real =
            2.0 * SYSTEM_CLOCK_HZ * (m as f64 + m_frac as f64 / 65536.0) / (1u32 << MOD_N) as f64;
        Ok(Self {
            m,
            m_frac,
            n: MOD_N,
            ps,
            vco_hz: vco_real,
            modulation_hz: vco_real / (q * (ps + 1) as f64),
        })
    }
}

/// The modulation frequencies the PLL reaches: VCO in [300, 600] MHz
/// divided by quads * (1 + mod_ps), mod_ps <= 7.
pub fn modulation_range_hz(quads: u32) -> Range {
    let q = f64::from(quads.max(1));
    Range {
        name: "modulation_hz",
        unit: "Hz",
        min: VCO_MIN_HZ / (q * f64::from(MOD_PS_MAX + 1)),
        max: VCO_MAX_HZ / q,
        min_set_by:
            "PLL: VCO >= 300 MHz, mod_ps <= 7 (lower needs an external generator wired to the LEDs)",
        max_set_by: "PLL: VCO <= 600 MHz",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs().max(1.0)
    }

    #[test]
    fn pll_matches_sdk_formula() {
        // 12 MHz, 4 quads: ps = floor(300/4/12) = 6, VCO = 7*4*12 = 336 MHz,
        // m = 336 * 4 / 96 = 14 exactly.
        let p = PllSettings::for_modulation(12e6, 4).unwrap();
        assert_eq!((p.ps, p.n, p.m, p.m_frac), (6, 2, 14, 0));
        assert!((p.modulation_hz - 12e6).abs() < 1.0);
        for f in [9.5e6, 10e6, 20e6, 48e6, 80e6] {
            let p = PllSettings::for_modulation(f, 4).unwrap();
            assert!(p.vco_hz >= VCO_MIN_HZ - 1e3 && p.vco_hz <= VCO_MAX_HZ + 1e3);
            assert!((p.modulation_hz - f).abs() / f < 1e-4, "{f}: {p:?}");
        }
    }

    #[test]
    fn stock_board_cannot_modulate_at_paper_frequencies() {
        for f in [1e6, 5e6, 9.3e6, f64::NAN, -1.0] {
            let e = PllSettings::for_modulation(f, 4).unwrap_err();
            assert!(e.to_string().contains("external generator"), "{e}");
        }
        assert!(PllSettings::for_modulation(9.375e6, 4).is_ok());
    }

    #[test]
    fn modulation_range_is_the_pll() {
        let r = modulation_range_hz(4);
        assert!(close(r.min, 9.375e6) && close(r.max, 150e6));
        let r = modulation_range_hz(6);
        assert!(close(r.min, 6.25e6) && close(r.max, 100e6));
    }
}
