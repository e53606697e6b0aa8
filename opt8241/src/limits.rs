//! The chip's arithmetic for what a configuration allows: frame rate,
//! exposure and modulation ranges, each with what sets its ends.
//!
//! Frame rate: pix_cnt_max (0x5882 [21:0], 22 bits) = f_sys / (fps x
//! quads x sub frames) must fit its field, which sets the lowest rate; the
//! firmware's laser-safety minimum pix_cnt_max and the output port set the
//! highest: a raw-quad frame is width * height * quads * 2 bytes, and the
//! SDK keeps it under 0.8 * op_clk bytes per second
//! (`TintinCDKCamera::_getMaximumFrameRate`, `_setStreamerFrameSize`).
//! Modulation: the PLL's reach ([`crate::pll::modulation_range_hz`]).

use crate::pll::modulation_range_hz;
use crate::range::{OutOfRange, Range};
use crate::registers::{field, safety, SYSTEM_CLOCK_HZ};
use crate::roi::Roi;

/// Output data clock with op_clk_freq = 0 (0x5C39 [2:1]: 24 MHz >> op_clk_freq).
pub const OP_CLK_MAX_HZ: f64 = 24e6;
/// Share of the output clock the SDK plans a frame rate for.
pub const OUTPUT_PORT_MARGIN: f64 = 0.8;
/// Bytes per pixel and quad in raw-quad output (12-bit samples in 16 bits).
pub const BYTES_PER_QUAD_SAMPLE: u64 = 2;

/// The three settable ranges for one configuration's quads, sub frames,
/// ROI and output clock.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardLimits {
    pub frame_rate_hz: Range,
    /// Over the whole frame-rate range: the shortest at the highest rate,
    /// the longest the laser-safety cap allows at the lowest.
    pub exposure_us: Range,
    pub modulation_hz: Range,
}

impl BoardLimits {
    /// The ranges for these quads, sub frames, ROI and output clock.
    pub fn new(quads: u32, sub_frames: u32, roi: Roi, op_clk_freq: u32) -> Self {
        let frame_rate_hz = frame_rate_range_hz(quads, sub_frames, roi, op_clk_freq);
        let shortest = exposure_range_us(frame_rate_hz.max, quads, sub_frames).min;
        let quad_at_slowest = quad_us(frame_rate_hz.min, quads, sub_frames);
        let exposure_us = Range {
            name: "exposure_us",
            unit: "us",
            min: shortest,
            max: quad_at_slowest * f64::from(safety::INTG_DUTY_CYCLE_MAX) / 64.0,
            min_set_by: "intg_duty_cycle 1 (of 64) at the highest frame rate",
            max_set_by: "laser safety: intg_duty_cycle <= 20 (of 64) at the lowest frame rate",
        };
        Self {
            frame_rate_hz,
            exposure_us,
            modulation_hz: modulation_range_hz(quads),
        }
    }
}

/// One quad's time, microseconds.
pub fn quad_us(frame_rate_hz: f64, quads: u32, sub_frames: u32) -> f64 {
    1e6 / (frame_rate_hz * f64::from(quads) * f64::from(sub_frames))
}

/// Output data clock for op_clk_freq (0: 24 MHz, 1: 12, 2: 6, 3: 3).
pub fn op_clk_hz(op_clk_freq: u32) -> f64 {
    OP_CLK_MAX_HZ / f64::from(1u32 << op_clk_freq.min(field::OP_CLK_FREQ.max()))
}

/// Bytes of one raw-quad frame.
pub fn bytes_per_frame(quads: u32, roi: Roi) -> u64 {
    roi.pixels() * u64::from(quads) * BYTES_PER_QUAD_SAMPLE
}

/// pix_cnt_max for a frame rate: f_sys / (fps * quads * sub frames)
/// (SDK `ToFCamera::_setFrameRate`).
pub fn pix_cnt_max_for(frame_rate_hz: f64, quads: u32, sub_frames: u32) -> u32 {
    (SYSTEM_CLOCK_HZ / (frame_rate_hz * f64::from(quads) * f64::from(sub_frames))).floor() as u32
}

/// intg_duty_cycle for an integration percentage: round(p * 64 / 100)
/// (SDK `IntegrationTimeParameter::set`).
pub fn intg_duty_cycle_for(integration_percent: f64) -> u32 {
    (integration_percent * 64.0 / 100.0).round() as u32
}

/// The frame rates the chip and its output port allow.
pub fn frame_rate_range_hz(quads: u32, sub_frames: u32, roi: Roi, op_clk_freq: u32) -> Range {
    let per_quad = f64::from(quads) * f64::from(sub_frames);
    let min = SYSTEM_CLOCK_HZ / (f64::from(field::PIX_CNT_MAX.max()) * per_quad);
    let safety_max = SYSTEM_CLOCK_HZ / (f64::from(safety::PIX_CNT_MAX_MIN) * per_quad);
    let bytes = bytes_per_frame(quads, roi).max(1) as f64;
    let port_max = OUTPUT_PORT_MARGIN * op_clk_hz(op_clk_freq) / bytes;
    let (max, max_set_by) = if port_max < safety_max {
        (
            port_max,
            "output port: 0.8 x op_clk / bytes per raw-quad frame",
        )
    } else {
        (safety_max, "laser safety: pix_cnt_max >= 60000")
    };
    Range {
        name: "frame_rate_hz",
        unit: "Hz",
        min,
        max,
        min_set_by: "pix_cnt_max is 22 bits",
        max_set_by,
    }
}

/// The exposures (one quad's integration) the chip holds at a frame rate:
/// intg_duty_cycle in [1, 63] of 64, rounded as the SDK rounds.
pub fn exposure_range_us(frame_rate_hz: f64, quads: u32, sub_frames: u32) -> Range {
    let quad = quad_us(frame_rate_hz, quads, sub_frames);
    Range {
        name: "exposure_us",
        unit: "us",
        min: quad * 0.5 / 64.0,
        max: quad * f64::from(field::INTG_DUTY_CYCLE.max()) / 64.0,
        min_set_by: "intg_duty_cycle rounds to at least 1 (of 64)",
        max_set_by: "intg_duty_cycle is 6 bits: 63 of 64 of the quad",
    }
}

fn discrete(name: &'static str, value: u32, min: u32, max: u32, why: &str) -> OutOfRange {
    OutOfRange {
        name,
        value: f64::from(value),
        min: f64::from(min),
        max: f64::from(max),
        unit: "",
        why: why.into(),
    }
}

/// quad_cnt_max: only 4 or 6 (OPT9221.dml).
pub fn check_quads(quads: u32) -> Result<(), OutOfRange> {
    match quads {
        4 | 6 => Ok(()),
        _ => Err(discrete("quads", quads, 4, 6, "quad_cnt_max: 4 or 6")),
    }
}

/// sub_frame_cnt_max: 1, 2, 4 or 8 (OPT9221.dml).
pub fn check_sub_frames(sub_frames: u32) -> Result<(), OutOfRange> {
    match sub_frames {
        1 | 2 | 4 | 8 => Ok(()),
        _ => Err(discrete(
            "sub_frames",
            sub_frames,
            1,
            8,
            "sub_frame_cnt_max: 1, 2, 4 or 8",
        )),
    }
}

/// op_clk_freq: 2 bits.
pub fn check_op_clk_freq(op_clk_freq: u32) -> Result<(), OutOfRange> {
    let max = field::OP_CLK_FREQ.max();
    if op_clk_freq <= max {
        Ok(())
    } else {
        Err(discrete(
            "op_clk_freq",
            op_clk_freq,
            0,
            max,
            "0: 24 MHz, 1: 12, 2: 6, 3: 3",
        ))
    }
}

/// Columns in multiples of 16 within 320, rows within 240 (SDK `_allowedROI`).
pub fn check_roi(r: Roi) -> Result<(), OutOfRange> {
    let ok = r.width > 0
        && r.height > 0
        && r.x.is_multiple_of(16)
        && r.width.is_multiple_of(16)
        && r.x
            .checked_add(r.width)
            .is_some_and(|e| e <= Roi::FULL.width)
        && r.y
            .checked_add(r.height)
            .is_some_and(|e| e <= Roi::FULL.height);
    if ok {
        Ok(())
    } else {
        Err(discrete(
            "roi width",
            r.width,
            16,
            Roi::FULL.width,
            "columns multiples of 16 within 320, rows within 240",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs().max(1.0)
    }

    #[test]
    fn lowest_frame_rate_is_where_pix_cnt_max_fills_22_bits() {
        // 48e6 / (4194303 * 4 * 1) = 2.86102 Hz
        let r = frame_rate_range_hz(4, 1, Roi::FULL, 0);
        assert!(close(r.min, 48e6 / (4_194_303.0 * 4.0)), "{r:?}");
        assert!((r.min - 2.861).abs() < 1e-3);
        assert!(pix_cnt_max_for(r.min, 4, 1) <= field::PIX_CNT_MAX.max());
        assert!(pix_cnt_max_for(r.min * 0.999, 4, 1) > field::PIX_CNT_MAX.max());
        // 6 quads, 2 sub frames: 48e6 / (4194303 * 12) = 0.9537 Hz
        let r = frame_rate_range_hz(6, 2, Roi::FULL, 0);
        assert!((r.min - 0.95367).abs() < 1e-4, "{r:?}");
    }

    #[test]
    fn highest_frame_rate_is_the_output_port_for_full_frames() {
        // 320 * 240 * 4 quads * 2 bytes = 614400 bytes; 0.8 * 24e6 / 614400 = 31.25 Hz
        assert_eq!(bytes_per_frame(4, Roi::FULL), 614_400);
        let r = frame_rate_range_hz(4, 1, Roi::FULL, 0);
        assert!(close(r.max, 31.25), "{r:?}");
        assert!(r.max_set_by.contains("output port"));
        // op_clk_freq = 1: 12 MHz, 15.625 Hz
        assert!(close(frame_rate_range_hz(4, 1, Roi::FULL, 1).max, 15.625));
        // 6 quads: 921600 bytes, 20.833 Hz
        assert!(close(
            frame_rate_range_hz(6, 1, Roi::FULL, 0).max,
            0.8 * 24e6 / 921_600.0
        ));
        // a 64 x 48 ROI: the laser-safety pix_cnt_max >= 60000 wins, 200 Hz
        let small = Roi {
            x: 0,
            y: 0,
            width: 64,
            height: 48,
        };
        let r = frame_rate_range_hz(4, 1, small, 0);
        assert!(
            close(r.max, 200.0) && r.max_set_by.contains("laser safety"),
            "{r:?}"
        );
    }

    #[test]
    fn exposure_is_a_sixty_fourth_of_the_quad_at_a_time() {
        // 30 Hz, 4 quads: quad 8333.3 us; duty 1..=63 of 64, rounded
        let r = exposure_range_us(30.0, 4, 1);
        assert!(close(r.min, 1e6 / 120.0 / 128.0));
        assert!(close(r.max, 1e6 / 120.0 * 63.0 / 64.0));
        assert!(r.check(8333.0).is_err());
        let l = BoardLimits::new(4, 1, Roi::FULL, 0);
        // shortest at 31.25 Hz, longest 20/64 of the quad at 2.861 Hz
        assert!(close(l.exposure_us.min, 1e6 / 125.0 / 128.0));
        assert!(close(
            l.exposure_us.max,
            1e6 * 4_194_303.0 / 48e6 * 20.0 / 64.0
        ));
    }

    #[test]
    fn discrete_settings_outside_their_values_are_refused() {
        assert!(
            check_quads(5).is_err()
                && check_sub_frames(3).is_err()
                && check_op_clk_freq(4).is_err()
        );
        assert!(check_roi(Roi {
            x: 8,
            y: 0,
            width: 64,
            height: 10
        })
        .is_err());
        assert!(check_roi(Roi {
            x: u32::MAX - 15,
            y: 0,
            width: 16,
            height: 10
        })
        .is_err());
    }
}
