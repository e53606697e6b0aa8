//! What the emulated OPT9221 does beyond storing registers: the state TI's
//! viewer leaves at power-on, when a new modulation PLL setting takes
//! effect, and saturated wells.

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
    (0x5C25, 2 << 18),        // op_data_arrange_mode 2: the chip's default (DML)
    (0x5C27, 2 << 11),        // pixel_data_size 2: depth without flags
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

/// A rectangle of pixels whose A and B wells both fill (ambient light
/// with the IR filter off): the raw quads, A - B, read 0 there, and depth
/// frames set the saturation flag (bit 3 of the flags nibble, OPT9221.dml
/// saturation_threshold; SDK `DenoiseFilter.cpp`) and a full ambient nibble.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SaturatedRegion {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl SaturatedRegion {
    pub fn contains(&self, x: usize, y: usize) -> bool {
        (self.x..self.x + self.width).contains(&x) && (self.y..self.y + self.height).contains(&y)
    }

    /// Both wells full: the difference of every quad is 0.
    pub fn fill_wells(&self, dn: &mut [f32], width: usize) {
        for (i, d) in dn.iter_mut().enumerate() {
            if self.contains(i % width, i / width) {
                *d = 0.0;
            }
        }
    }
}

/// What the output port streams: output_mode 15, or 0 with the depth
/// layout of pixel_data_size and op_data_arrange_mode (OPT9221.dml; SDK
/// `ToFFrameGenerator::_generateToFRawFrame`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    RawQuads,
    Depth(DepthLayout),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthLayout {
    /// 4 bytes, continuous: amplitude | ambient << 12, phase | flags << 12.
    Continuous,
    /// 4 bytes in chunks of 8 pixels: 8 amplitude words, then 8 phase words.
    Rearranged8,
    /// 2 bytes: phase | amplitude's top 4 bits << 12, no flags.
    TwoBytes,
}

impl Output {
    pub fn of(s: &super::BoardState) -> Option<Self> {
        let r = s.reg(0x5C25);
        match super::field(r, 11, 8) {
            15 => Some(Output::RawQuads),
            0 => match (super::field(s.reg(0x5C27), 14, 11), super::field(r, 19, 18)) {
                (4, 2) => Some(Output::Depth(DepthLayout::Rearranged8)),
                (4, _) => Some(Output::Depth(DepthLayout::Continuous)),
                (2, _) => Some(Output::Depth(DepthLayout::TwoBytes)),
                _ => None,
            },
            _ => None,
        }
    }
}

/// A depth frame of a flat scene: amplitude 200 and ambient 2 outside
/// `region`, amplitude 0, ambient 15 and the saturation flag inside.
pub fn encode_depth(
    width: usize,
    height: usize,
    region: Option<SaturatedRegion>,
    layout: DepthLayout,
) -> Vec<u8> {
    let words = |i: usize| -> (u16, u16) {
        let sat = region.is_some_and(|r| r.contains(i % width, i / width));
        let (amplitude, ambient, flags) = if sat {
            (0u16, 0xFu16, 0x8u16)
        } else {
            (200, 2, 0)
        };
        (amplitude | (ambient << 12), 0x123 | (flags << 12))
    };
    let mut out: Vec<u16> = Vec::with_capacity(width * height * 2);
    match layout {
        DepthLayout::Continuous => {
            for i in 0..width * height {
                let (a, p) = words(i);
                out.extend([a, p]);
            }
        }
        DepthLayout::Rearranged8 => {
            for chunk in (0..width * height).collect::<Vec<_>>().chunks(8) {
                out.extend(chunk.iter().map(|&i| words(i).0));
                out.extend(chunk.iter().map(|&i| words(i).1));
            }
        }
        DepthLayout::TwoBytes => {
            for i in 0..width * height {
                let (a, p) = words(i);
                out.push((p & 0xFFF) | ((a & 0xF00) << 4));
            }
        }
    }
    out.iter().flat_map(|w| w.to_le_bytes()).collect()
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;
    use std::time::{Duration, Instant};

    use sdi_opt8241::plan::{open_plan, Step};
    use sdi_opt8241::BoardConfig;

    use super::{pll_in_effect, RegisterWrite};

    /// The writes `steps` make, read-modify-write, 1 ms apart plus the sleeps.
    fn timed_writes(steps: &[Step]) -> Vec<RegisterWrite> {
        let mut regs = HashMap::<u16, u32>::new();
        let mut at = Instant::now();
        let mut out = Vec::new();
        for s in steps {
            match s {
                Step::Write { field, value, .. } => {
                    let reg = regs.entry(field.address).or_insert(0);
                    *reg = field.insert(*reg, *value).unwrap();
                    at += Duration::from_millis(1);
                    out.push(RegisterWrite {
                        address: field.address,
                        written: *reg,
                        kept: *reg,
                        at,
                    });
                }
                Step::Sleep { ms, .. } => at += Duration::from_millis(*ms),
                Step::Expect { .. } => {}
            }
        }
        out
    }

    #[test]
    fn the_pll_takes_the_plans_setting_and_not_the_old_sequences() {
        let plan = open_plan(&BoardConfig::default()).unwrap();
        let writes = timed_writes(&plan.steps);
        let fields =
            |w: &[RegisterWrite], a: u16| w.iter().rev().find(|w| w.address == a).unwrap().kept;
        assert_eq!(
            pll_in_effect(&writes),
            Some([fields(&writes, 0x580C), fields(&writes, 0x580F)])
        );
        // The sequence before the SDK's was followed: update 1, the fields,
        // update 0 at once; no settle, no trailing pulse.
        let old: Vec<Step> = plan
            .steps
            .iter()
            .copied()
            .filter(|s| match s {
                Step::Sleep { .. } => false,
                Step::Write { why, .. } => !why.starts_with("trailing PLL update pulse"),
                Step::Expect { .. } => true,
            })
            .collect();
        assert_eq!(old.len() + 3, plan.steps.len());
        assert_eq!(pll_in_effect(&timed_writes(&old)), None);
    }
}
