//! What the emulated OPT9221 does beyond storing registers: the state TI's
//! viewer leaves at power-on, and when a new modulation PLL setting takes
//! effect.

use std::time::{Duration, Instant};

use super::RegisterWrite;

/// Registers as TI's viewer leaves them after its default profile
/// (`TintinCDKCameraLongRange.conf`: 6 quads, 2 sub frames, dealiasing on,
/// spread spectrum on) and the chip's own defaults sdid must override
/// (tillum_slv_addr 0x71, binning off).
pub const LEFTOVER_PROFILE: &[(u16, u32)] = &[
    (0x5883, 0x26),           // sub_frame_cnt_max 2, quad_cnt_max 6
    (0x5C02, 1 << 23),        // dealias_en
    (0x5812, 1 << 7),         // quad_hop_en
    (0x5C4D, 1 << 6),         // normal_frm_intg_scale 1
    (0x5C31, 3 << 4),         // amplitude_scale 3
    (0x5C2E, 0x71),           // tillum_slv_addr: the chip's default
    (0x5C39, 1 << 1),         // op_clk_freq 1 (12 MHz)
    (0x580E, 1 << 3),         // sscg_en
    (0x580D, (16 << 16) | 5), // mod_m2, mod_m_frac2: a second frequency
];

/// The PLL settles this long after its fields before an update edge takes
/// them (OPT9221.dml mod_pll_update; SDK `TintinVCOFrequency::set` waits 10 ms).
pub const PLL_SETTLE: Duration = Duration::from_millis(10);

/// Registers holding the first PLL's fields (mod_m1/mod_m_frac1, mod_n1/mod_ps1).
const PLL_REGISTERS: [u16; 2] = [0x580C, 0x580F];
const PLL_UPDATE: u16 = 0x5802;

/// The PLL register values in effect after `writes`: taken on a
/// mod_pll_update 1 -> 0 edge that comes at least [`PLL_SETTLE`] after the
/// last PLL field write; `None` while the power-on setting still runs.
pub fn pll_in_effect(writes: &[RegisterWrite]) -> Option<[u32; 2]> {
    let mut fields = [None::<u32>; 2];
    let mut last_field_at: Option<Instant> = None;
    let mut update = 0;
    let mut effective = None;
    for w in writes {
        if let Some(i) = PLL_REGISTERS.iter().position(|&a| a == w.address) {
            fields[i] = Some(w.kept);
            last_field_at = Some(w.at);
        } else if w.address == PLL_UPDATE {
            let next = (w.kept >> 2) & 1;
            let settled = last_field_at.is_none_or(|t| w.at.duration_since(t) >= PLL_SETTLE);
            if update == 1 && next == 0 && settled {
                if let [Some(a), Some(b)] = fields {
                    effective = Some([a, b]);
                }
            }
            update = next;
        }
    }
    effective
}

/// The board sensor's temperature the emulator reports (tsensor), C.
pub const SENSOR_C: i8 = 35;
/// The illumination driver's temperature (tillum) when tillum_slv_addr
/// names the CDK's sensor, 0x72, C.
pub const ILLUMINATION_C: i8 = 31;
/// What tillum reads when tillum_slv_addr names no sensor: nothing
/// answers on the I2C bus, all ones.
pub const NO_SENSOR: u32 = 0xFF;

/// A register read as the chip answers it: temperatures from their
/// sensors, op_overflow (0x5C63 [20]) set while the configured frame
/// outruns the output port (24 MHz >> op_clk_freq bytes per second) or
/// the test forces it, everything else as stored.
pub fn read(s: &super::BoardState, address: u16) -> u32 {
    match address {
        0x5C61 => u32::from(SENSOR_C as u8),
        0x5C62 if s.reg(0x5C2E) & 0x7F == 0x72 => u32::from(ILLUMINATION_C as u8),
        0x5C62 => NO_SENSOR,
        0x5C63 if s.force_overflow || outruns_output_port(s) => s.reg(address) | (1 << 20),
        _ => s.reg(address),
    }
}

/// Bytes per second the configured raw-quad stream needs against what
/// the output port carries.
fn outruns_output_port(s: &super::BoardState) -> bool {
    let (width, height, quads) = s.geometry();
    let bytes = (width * height * quads * 2) as f64;
    let op_clk_hz = 24e6 / f64::from(1u32 << super::field(s.reg(0x5C39), 2, 1));
    let streaming = super::field(s.reg(0x5880), 0, 0) == 0;
    streaming && bytes / s.frame_period().as_secs_f64() > op_clk_hz
}
