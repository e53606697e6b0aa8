//! Capture settings in the board's terms: exposure as integration duty
//! cycle, the board's limits, the sensor parameters it runs with.

use sdi_core::sensor::{SensorParams, SensorPreset};
use sdi_opt8241::{BoardConfig, PllSettings, Roi};

use crate::backend::opt8241::Opt8241;
use crate::backend::Limits;

/// Integration time of one quad, microseconds: intg_duty_cycle / 64 of the
/// quad time 1 / (fps * quads * sub frames) (OPT9221.dml; SDK
/// `IntegrationTimeParameter`).
pub fn exposure_us_of(c: &BoardConfig) -> f64 {
    let quad_us = 1e6 / (c.frame_rate_hz * f64::from(c.quads * c.sub_frames));
    c.integration_percent / 100.0 * quad_us
}

/// Inverse of [`exposure_us_of`]: the integration percentage for an exposure.
pub fn integration_percent_for(exposure_us: f64, c: &BoardConfig) -> f64 {
    let quad_us = 1e6 / (c.frame_rate_hz * f64::from(c.quads * c.sub_frames));
    exposure_us / quad_us * 100.0
}

/// The board's ranges for its quads, sub frames, ROI and output clock
/// (`sdi_opt8241::limits`): frame rate from the 22-bit pix_cnt_max up to
/// the output port or the laser-safety minimum pix_cnt_max, modulation
/// from its PLL, exposure up to the firmware's duty-cycle cap.
pub fn board_limits(c: &BoardConfig) -> Limits {
    let l = c.limits();
    Limits {
        exposure_us: l.exposure_us.bounds(),
        frame_rate_hz: l.frame_rate_hz.bounds(),
        modulation_hz: l.modulation_hz.bounds(),
    }
}

/// The OPT8241 preset with the board's geometry and settings.
pub(super) fn sensor_for(c: &BoardConfig) -> SensorParams {
    let mut p = SensorPreset::TiOpt8241.params();
    p.width = c.roi.width as usize;
    p.height = c.roi.height as usize;
    p.frame_rate_hz = c.frame_rate_hz;
    p.exposure_us = exposure_us_of(c);
    p.modulation_hz = PllSettings::for_modulation(c.modulation_hz, c.quads)
        .map_or(c.modulation_hz, |pll| pll.modulation_hz);
    p
}

/// [`sensor_for`] with the exposure the board kept (intg_duty_cycle as read
/// back, after any laser-safety clamp).
pub(super) fn actual_sensor(board: &Opt8241) -> SensorParams {
    let mut p = sensor_for(board.config());
    if let Some(w) = board
        .init_report()
        .writes
        .iter()
        .rev()
        .find(|w| w.field.name == "intg_duty_cycle")
    {
        let mut kept = board.config().clone();
        kept.integration_percent = f64::from(w.actual) * 100.0 / 64.0;
        p.exposure_us = exposure_us_of(&kept);
    }
    p
}

/// The board's configuration for `[board]` settings and the capture overrides.
pub fn board_config(
    roi: Option<Roi>,
    frame_rate_hz: Option<f64>,
    exposure_us: Option<f64>,
    modulation_hz: Option<f64>,
) -> BoardConfig {
    BoardConfig::with_capture(roi, frame_rate_hz, exposure_us, modulation_hz)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exposure_and_integration_are_inverse() {
        let c = BoardConfig::default();
        // 30 Hz, 4 quads: quad time 8333 us; 20 % of it.
        assert!((exposure_us_of(&c) - 1666.67).abs() < 0.01);
        let p = integration_percent_for(exposure_us_of(&c), &c);
        assert!((p - c.integration_percent).abs() < 1e-9);
    }

    #[test]
    fn limits_follow_the_safety_minimum_and_the_pll() {
        let l = board_limits(&BoardConfig::default());
        // 48 MHz / ((2^22 - 1) * 4) = 2.861 Hz; 0.8 * 24 MHz / 614400 bytes = 31.25 Hz
        assert!((l.frame_rate_hz.0 - 2.861).abs() < 1e-3, "{l:?}");
        assert!((l.frame_rate_hz.1 - 31.25).abs() < 1e-9, "{l:?}");
        // 300 MHz / (4 * 8) = 9.375 MHz: the board cannot go lower with 4 quads
        assert!((l.modulation_hz.0 - 9.375e6).abs() < 1.0);
        assert!(l.modulation_hz.0 > 9.3e6 && l.modulation_hz.0 < 9.5e6);
        // 20/64 of a quad at the lowest frame rate
        assert!((l.exposure_us.1 - 20.0 / 64.0 * 1e6 / (4.0 * l.frame_rate_hz.0)).abs() < 1e-6);
    }

    #[test]
    fn board_config_maps_overrides() {
        let c = board_config(None, Some(15.0), Some(1000.0), Some(20e6));
        assert_eq!(c.frame_rate_hz, 15.0);
        assert_eq!(c.modulation_hz, 20e6);
        assert!((exposure_us_of(&c) - 1000.0).abs() < 1e-6);
        let s = sensor_for(&c);
        assert_eq!((s.width, s.height), (320, 240));
        assert!((s.modulation_hz - 20e6).abs() / 20e6 < 1e-3);
    }
}
