//! The exact register sequence that opens and configures the board, as
//! data: sdid executes it ([`crate::configure`]) and
//! `sdictl board plan` prints it, so what a user diffs against TI's SDK is
//! what sdid does.
//!
//! Order: TI Voxel SDK `TintinCDKCamera::_init` (illumination temperature
//! sensor, bulk framing), `ToFTintinCamera::_init` (output handshake,
//! trailing PLL update pulse), `TintinVCOFrequency::set` (PLL fields inside
//! the update, 10 ms settle), `ToFCamera::_setBinning`,
//! `ToFCamera::_setFrameRate` (pix_cnt_max, then integration again). Every
//! field TI's profiles (`TintinCDKCamera*.conf`) set that changes raw-quad
//! output is written explicitly, so nothing a previous user, TI's viewer
//! or the boot flash left (a 6-quad dealiasing profile) survives the open.

use serde::Serialize;

use crate::config::BoardConfig;
use crate::depth_frame;
use crate::limits::{intg_duty_cycle_for, pix_cnt_max_for};
use crate::pll::PllSettings;
use crate::range::OutOfRange;
use crate::registers::{field, safety, Field, CDK_TILLUM_SLAVE_ADDRESS};

/// Settle time after the PLL fields, before mod_pll_update goes back to 0
/// (SDK `TintinVCOFrequency::set`).
pub const PLL_SETTLE_MS: u64 = 10;

/// One thing done to the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Read-modify-write of one field, read back.
    Write {
        field: Field,
        value: u32,
        why: &'static str,
    },
    Sleep {
        ms: u64,
        why: &'static str,
    },
    /// Read one field; anything but `value` fails the configuration.
    Expect {
        field: Field,
        value: u32,
        why: &'static str,
    },
}

/// A laser-safety limit the plan applies instead of the value asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlannedClamp {
    pub field: &'static str,
    pub requested: u32,
    pub actual: u32,
    pub reason: &'static str,
}

/// The whole open-and-configure sequence for one [`BoardConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    pub steps: Vec<Step>,
    pub pll: PllSettings,
    pub clamps: Vec<PlannedClamp>,
}

/// One step as `sdictl board plan --json` prints it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct StepLine {
    pub op: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub register: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub address: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bits: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub value: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ms: Option<u64>,
    pub why: &'static str,
}

impl Step {
    pub fn line(&self) -> StepLine {
        let reg = |f: &Field| {
            (
                Some(f.name),
                Some(format!("0x{:04X}", f.address)),
                Some(format!("[{}:{}]", f.msb, f.lsb)),
            )
        };
        match self {
            Step::Write { field, value, why } | Step::Expect { field, value, why } => {
                let (register, address, bits) = reg(field);
                StepLine {
                    op: if matches!(self, Step::Write { .. }) {
                        "write"
                    } else {
                        "expect"
                    },
                    register,
                    address,
                    bits,
                    value: Some(*value),
                    ms: None,
                    why,
                }
            }
            Step::Sleep { ms, why } => StepLine {
                op: "sleep",
                register: None,
                address: None,
                bits: None,
                value: None,
                ms: Some(*ms),
                why,
            },
        }
    }
}

impl std::fmt::Display for Step {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Step::Write { field, value, why } => write!(
                f,
                "write  {:<24} 0x{:04X} [{:>2}:{:>2}] = {:<8} # {why}",
                field.name, field.address, field.msb, field.lsb, value
            ),
            Step::Expect { field, value, why } => write!(
                f,
                "expect {:<24} 0x{:04X} [{:>2}:{:>2}] = {:<8} # {why}",
                field.name, field.address, field.msb, field.lsb, value
            ),
            Step::Sleep { ms, why } => write!(f, "sleep  {ms} ms{:<33} # {why}", ""),
        }
    }
}

/// The sequence for `config`, or why the board cannot do it (checked
/// before any step exists, so a refused configuration writes nothing).
pub fn open_plan(config: &BoardConfig) -> Result<Plan, OutOfRange> {
    config.validate()?;
    let pll = PllSettings::for_modulation(config.modulation_hz, config.quads)?;
    let mut steps = Vec::with_capacity(48);
    let mut w = |field: Field, value: u32, why: &'static str| {
        steps.push(Step::Write { field, value, why });
    };
    const KNOWN: &str = "known state: undo what an earlier profile left";
    w(
        field::TG_DIS,
        1,
        "stop the timing generator while configuring",
    );
    w(
        field::TILLUM_SLV_ADDR,
        CDK_TILLUM_SLAVE_ADDRESS,
        "the CDK's illumination temperature sensor",
    );
    w(
        field::BLK_HEADER_EN,
        0,
        "bulk framing: no UVC block headers",
    );
    w(field::BLK_SIZE, 512, "bulk framing: 512-byte blocks");
    w(field::OP_CS_POL, 1, "output handshake, as the SDK");
    w(field::FB_READY_EN, 1, "output handshake, as the SDK");
    w(
        field::OP_CLK_FREQ,
        config.op_clk_freq,
        "output clock 24 MHz >> op_clk_freq",
    );
    w(field::DEALIAS_EN, 0, KNOWN);
    w(field::QUAD_HOP_EN, 0, KNOWN);
    w(field::HDR_SCALE, 0, KNOWN);
    w(field::NORMAL_FRM_INTG_SCALE, 0, KNOWN);
    w(field::AMPLITUDE_SCALE, 0, KNOWN);
    w(field::SSCG_EN, 0, "no spread spectrum: a clean square wave");
    w(
        field::QUAD_CNT_MAX,
        config.quads,
        "quads (the PLL divides by it)",
    );
    w(field::SUB_FRAME_CNT_MAX, config.sub_frames, "sub frames");
    w(field::MOD_PLL_UPDATE, 1, "PLL update: fields follow");
    w(field::MOD_M1, pll.m, "PLL 1");
    w(field::MOD_N1, pll.n, "PLL 1");
    w(field::MOD_M_FRAC1, pll.m_frac, "PLL 1");
    w(field::MOD_PS1, pll.ps, "PLL 1 prescaler");
    w(field::MOD_M2, pll.m, "PLL 2 = PLL 1 (no dealiasing)");
    w(field::MOD_N2, pll.n, "PLL 2 = PLL 1 (no dealiasing)");
    w(
        field::MOD_M_FRAC2,
        pll.m_frac,
        "PLL 2 = PLL 1 (no dealiasing)",
    );
    w(field::MOD_PS2, pll.ps, "PLL 2 = PLL 1 (no dealiasing)");
    steps.push(Step::Sleep {
        ms: PLL_SETTLE_MS,
        why: "PLL settles, as the SDK",
    });
    let mut w = |field: Field, value: u32, why: &'static str| {
        steps.push(Step::Write { field, value, why });
    };
    w(field::MOD_PLL_UPDATE, 0, "PLL update ends");
    let r = config.roi;
    w(field::ROW_START, r.y, "ROI rows");
    w(field::ROW_END, r.y + r.height - 1, "ROI rows");
    w(field::COL_START, r.x / 16, "ROI columns / 16");
    w(field::COL_END, (r.x + r.width) / 16 - 1, "ROI columns / 16");
    w(
        field::ROWS_TO_MERGE,
        1,
        "binning as the SDK: on, merge factors 1",
    );
    w(
        field::COLS_TO_MERGE,
        1,
        "binning as the SDK: on, merge factors 1",
    );
    w(field::BIN_ROW_COUNT, r.height, "output rows");
    w(field::BIN_COL_COUNT, r.width, "output columns");
    w(
        field::BINNING_EN,
        1,
        "binning as the SDK: on, merge factors 1",
    );
    w(
        field::OUTPUT_MODE,
        depth_frame::OUTPUT_MODE_RAW_QUADS,
        "raw quads out",
    );
    w(
        field::PIXEL_DATA_SIZE,
        depth_frame::PIXEL_DATA_SIZE_4_BYTES,
        "saturation probe's depth frames: 4 bytes, with flags",
    );
    w(
        field::OP_DATA_ARRANGE_MODE,
        depth_frame::OP_DATA_ARRANGE_CONTINUOUS,
        "saturation probe's depth frames: pixel by pixel",
    );
    w(
        field::DEBUG_FRAME_NUMBER_EN,
        u32::from(config.frame_numbers),
        "frame number in the first byte (alignment check)",
    );
    let pix = pix_cnt_max_for(config.frame_rate_hz, config.quads, config.sub_frames);
    w(
        field::PIX_CNT_MAX,
        pix,
        "frame rate: 48 MHz / (fps x quads x sub frames)",
    );
    let mut clamps = Vec::new();
    let requested = intg_duty_cycle_for(config.integration_percent);
    let duty = requested.min(safety::INTG_DUTY_CYCLE_MAX);
    if duty != requested {
        clamps.push(PlannedClamp {
            field: field::INTG_DUTY_CYCLE.name,
            requested,
            actual: duty,
            reason: "laser safety: intg_duty_cycle <= 20",
        });
    }
    w(
        field::INTG_DUTY_CYCLE,
        duty,
        "integration after the frame rate, as the SDK",
    );
    w(field::TG_DIS, 0, "restart the timing generator");
    w(
        field::MOD_PLL_UPDATE,
        1,
        "trailing PLL update pulse, as the SDK",
    );
    w(
        field::MOD_PLL_UPDATE,
        0,
        "trailing PLL update pulse, as the SDK",
    );
    steps.push(Step::Expect {
        field: field::PIX_CNT_MAX_SET_FAILED,
        value: 0,
        why: "the chip took the frame rate",
    });
    steps.push(Step::Expect {
        field: field::INTG_DUTY_CYCLE_SET_FAILED,
        value: 0,
        why: "the chip took the integration",
    });
    Ok(Plan { steps, pll, clamps })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn writes(p: &Plan) -> Vec<(&'static str, u32)> {
        p.steps
            .iter()
            .filter_map(|s| match s {
                Step::Write { field, value, .. } => Some((field.name, *value)),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn pll_update_is_the_sdks_one_settle_and_a_trailing_pulse() {
        let p = open_plan(&BoardConfig::default()).unwrap();
        let at = |want: &Step| p.steps.iter().position(|s| s == want).unwrap();
        let first_up = p
            .steps
            .iter()
            .position(|s| matches!(s, Step::Write { field, value: 1, .. } if field.name == "mod_pll_update"))
            .unwrap();
        let sleep = at(&Step::Sleep {
            ms: 10,
            why: "PLL settles, as the SDK",
        });
        assert!(sleep > first_up);
        for s in &p.steps[first_up + 1..sleep] {
            let Step::Write { field, .. } = s else {
                panic!("{s}")
            };
            assert!(field.name.starts_with("mod_"), "{s}");
        }
        assert!(
            matches!(p.steps[sleep + 1], Step::Write { field, value: 0, .. } if field.name == "mod_pll_update")
        );
        let w = writes(&p);
        let n = w.len();
        assert_eq!(
            &w[n - 3..],
            &[("tg_dis", 0), ("mod_pll_update", 1), ("mod_pll_update", 0)]
        );
        assert_eq!(w[0], ("tg_dis", 1));
    }

    #[test]
    fn every_profile_field_is_written_explicitly() {
        let w = writes(&open_plan(&BoardConfig::default()).unwrap());
        for (name, value) in [
            ("op_clk_freq", 0),
            ("dealias_en", 0),
            ("quad_hop_en", 0),
            ("hdr_scale", 0),
            ("normal_frm_intg_scale", 0),
            ("amplitude_scale", 0),
            ("binning_en", 1),
            ("rows_to_merge", 1),
            ("cols_to_merge", 1),
            ("tillum_slv_addr", 0x72),
            ("quad_cnt_max", 4),
            ("sub_frame_cnt_max", 1),
            ("mod_m2", 14),
            ("mod_ps2", 6),
            ("pix_cnt_max", 400_000),
            ("intg_duty_cycle", 13),
            ("output_mode", 15),
            ("pixel_data_size", 4),
            ("op_data_arrange_mode", 0),
        ] {
            assert!(
                w.contains(&(name, value)),
                "{name} = {value} missing from {w:?}"
            );
        }
    }

    #[test]
    fn a_refused_configuration_has_no_plan() {
        let c = BoardConfig {
            frame_rate_hz: 1.0,
            ..BoardConfig::default()
        };
        assert_eq!(open_plan(&c).unwrap_err().name, "frame_rate_hz");
    }

    #[test]
    fn laser_safety_caps_the_duty_cycle_and_says_so() {
        let c = BoardConfig {
            integration_percent: 80.0,
            ..BoardConfig::default()
        };
        let p = open_plan(&c).unwrap();
        assert_eq!(p.clamps.len(), 1);
        assert_eq!((p.clamps[0].requested, p.clamps[0].actual), (51, 20));
        assert!(writes(&p).contains(&("intg_duty_cycle", 20)));
    }
}
