//! What sdid asks of the board: quads, sub frames, modulation, frame rate,
//! integration, region of interest and output clock.

use crate::limits::{self, BoardLimits};
use crate::pll::PllSettings;
use crate::range::OutOfRange;
use crate::roi::Roi;

/// What sdid asks of the board.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardConfig {
    /// quad_cnt_max: 4 or 6.
    pub quads: u32,
    /// sub_frame_cnt_max: 1, 2, 4 or 8.
    pub sub_frames: u32,
    /// Modulation (carrier) frequency of f(t). The stock board reaches
    /// down to about 9.4 MHz with 4 quads; lower needs an external generator.
    pub modulation_hz: f64,
    pub frame_rate_hz: f64,
    /// Integration as a fraction of the quad time, percent (the firmware
    /// caps it at 20/64 = 31 %).
    pub integration_percent: f64,
    pub roi: Roi,
    /// op_clk_freq: output clock 24 MHz >> op_clk_freq (0..=3).
    pub op_clk_freq: u32,
    /// debug_frame_number_en: frame number in the first byte (alignment check).
    pub frame_numbers: bool,
}

impl Default for BoardConfig {
    fn default() -> Self {
        Self {
            quads: 4,
            sub_frames: 1,
            modulation_hz: 12e6,
            frame_rate_hz: 30.0,
            integration_percent: 20.0,
            roi: Roi::FULL,
            op_clk_freq: 0,
            frame_numbers: true,
        }
    }
}

impl BoardConfig {
    /// Rejects NaN, infinities and values the chip cannot hold, naming the
    /// valid range ([`limits`]); nothing here touches the board.
    pub fn validate(&self) -> Result<(), OutOfRange> {
        limits::check_quads(self.quads)?;
        limits::check_sub_frames(self.sub_frames)?;
        limits::check_roi(self.roi)?;
        limits::check_op_clk_freq(self.op_clk_freq)?;
        let l = self.limits();
        l.frame_rate_hz.check(self.frame_rate_hz)?;
        limits::exposure_range_us(self.frame_rate_hz, self.quads, self.sub_frames)
            .check(self.exposure_us())?;
        PllSettings::for_modulation(self.modulation_hz, self.quads)?;
        Ok(())
    }

    /// The ranges the chip allows with these quads, sub frames, ROI and
    /// output clock.
    pub fn limits(&self) -> BoardLimits {
        BoardLimits::new(self.quads, self.sub_frames, self.roi, self.op_clk_freq)
    }

    /// Integration time of one quad: intg_duty_cycle / 64 of the quad time
    /// 1 / (fps * quads * sub frames) (OPT9221.dml; SDK `IntegrationTimeParameter`).
    pub fn exposure_us(&self) -> f64 {
        self.integration_percent / 100.0
            * limits::quad_us(self.frame_rate_hz, self.quads, self.sub_frames)
    }

    /// The defaults with the capture settings a user gives (sdid's
    /// `sdid.toml` and flags, `sdictl board plan`); the exposure is set
    /// last, since it is a share of the quad time at the frame rate.
    pub fn with_capture(
        roi: Option<Roi>,
        frame_rate_hz: Option<f64>,
        exposure_us: Option<f64>,
        modulation_hz: Option<f64>,
    ) -> Self {
        let mut c = Self::default();
        if let Some(r) = roi {
            c.roi = r;
        }
        if let Some(f) = frame_rate_hz {
            c.frame_rate_hz = f;
        }
        if let Some(m) = modulation_hz {
            c.modulation_hz = m;
        }
        if let Some(e) = exposure_us {
            c.integration_percent = c.integration_percent_for(e);
        }
        c
    }

    /// Inverse of [`BoardConfig::exposure_us`].
    pub fn integration_percent_for(&self, exposure_us: f64) -> f64 {
        exposure_us / limits::quad_us(self.frame_rate_hz, self.quads, self.sub_frames) * 100.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_of_range_names_the_range_and_its_cause() {
        let c = BoardConfig {
            frame_rate_hz: 1.0,
            ..BoardConfig::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.name, "frame_rate_hz");
        let text = e.to_string();
        assert!(
            text.contains("2.86") && text.contains("31.25") && text.contains("22 bits"),
            "{text}"
        );
        let c = BoardConfig {
            frame_rate_hz: 60.0,
            ..BoardConfig::default()
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("output port"));
        for bad in [f64::NAN, f64::INFINITY, -1.0] {
            let c = BoardConfig {
                frame_rate_hz: bad,
                ..BoardConfig::default()
            };
            assert!(c.validate().is_err());
        }
        assert!(BoardConfig::default().validate().is_ok());
    }
}
