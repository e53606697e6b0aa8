//! Board configuration: executes the open plan ([`crate::plan`], the same
//! sequence `sdictl board plan` prints) over a [`RegisterBus`].
//!
//! Every write is read back; values the firmware clamped are reported in
//! [`InitReport::clamps`], never worked around. A configuration the chip
//! cannot hold is refused before the first transfer.

use std::time::Duration;

use crate::config::BoardConfig;
use crate::plan::{open_plan, Step};
use crate::pll::PllSettings;
use crate::protocol::{FieldWrite, ProtocolError, RegisterBus, Transport};
use crate::range::OutOfRange;
use crate::raw_quads::QuadLayout;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error(transparent)]
    OutOfRange(#[from] OutOfRange),
    #[error(transparent)]
    Protocol(#[from] ProtocolError),
    #[error("board reports {field} = {value} after configuration (expected {expected})")]
    StatusFlag {
        field: &'static str,
        value: u32,
        expected: u32,
    },
}

/// A value the board (or our own limit) changed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Clamp {
    pub field: &'static str,
    pub requested: u32,
    pub actual: u32,
    pub reason: &'static str,
}

/// Everything configuration did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct InitReport {
    pub writes: Vec<FieldWrite>,
    pub clamps: Vec<Clamp>,
    pub pll: Option<PllSettings>,
    pub layout: Option<QuadLayout>,
    pub firmware_version: Option<(u8, u8)>,
}

impl InitReport {
    fn record(&mut self, w: FieldWrite, reason: &'static str) {
        if w.clamped() {
            self.clamps.push(Clamp {
                field: w.field.name,
                requested: w.requested,
                actual: w.actual,
                reason,
            });
        }
        self.writes.push(w);
    }
}

/// The frame geometry the board streams for `config`.
pub fn layout_of(config: &BoardConfig) -> QuadLayout {
    QuadLayout {
        width: config.roi.width as usize,
        height: config.roi.height as usize,
        quads: config.quads as usize,
    }
}

/// Runs the open plan on an opened board. Clamps are in the report, for
/// the caller to log.
pub fn configure<T: Transport>(
    bus: &mut RegisterBus<T>,
    config: &BoardConfig,
) -> Result<InitReport, ConfigError> {
    let plan = open_plan(config)?;
    let mut report = InitReport {
        firmware_version: bus.firmware_version().ok(),
        ..Default::default()
    };
    for c in &plan.clamps {
        report.clamps.push(Clamp {
            field: c.field,
            requested: c.requested,
            actual: c.actual,
            reason: c.reason,
        });
    }
    for step in &plan.steps {
        match *step {
            Step::Write { field, value, .. } => {
                let w = bus.write_field(field, value)?;
                report.record(w, "board kept a different value");
            }
            Step::Sleep { ms, .. } => std::thread::sleep(Duration::from_millis(ms)),
            Step::Expect { field, value, .. } => {
                let got = bus.read_field(field)?;
                if got != value {
                    return Err(ConfigError::StatusFlag {
                        field: field.name,
                        value: got,
                        expected: value,
                    });
                }
            }
        }
    }
    report.pll = Some(plan.pll);
    report.layout = Some(layout_of(config));
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::tests::FakeBoard;
    use crate::registers::{field, Field};
    use crate::roi::Roi;

    #[test]
    fn configure_writes_the_sdk_sequence_and_reads_back() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        let report = configure(&mut bus, &BoardConfig::default()).unwrap();
        assert!(report.clamps.is_empty(), "{:?}", report.clamps);
        let regs = &bus.transport().registers;
        let get = |f: Field| f.extract(regs.get(&f.address).copied().unwrap_or(0));
        assert_eq!(get(field::TG_DIS), 0);
        assert_eq!(get(field::OUTPUT_MODE), 15);
        assert_eq!(get(field::QUAD_CNT_MAX), 4);
        assert_eq!(get(field::PIX_CNT_MAX), 400_000);
        assert_eq!(get(field::INTG_DUTY_CYCLE), 13);
        assert_eq!(get(field::DEBUG_FRAME_NUMBER_EN), 1);
        assert_eq!(get(field::BLK_SIZE), 512);
        assert_eq!(get(field::COL_END), 19);
        assert_eq!(get(field::ROW_END), 239);
        // first write stops the TG; the TG restarts before the trailing PLL pulse
        let first = report.writes.first().unwrap();
        assert_eq!((first.field.name, first.requested), ("tg_dis", 1));
        let names: Vec<_> = report.writes.iter().map(|w| w.field.name).collect();
        let n = names.len();
        assert_eq!(
            &names[n - 3..],
            &["tg_dis", "mod_pll_update", "mod_pll_update"]
        );
        // every step of the plan was executed, in order
        let plan = open_plan(&BoardConfig::default()).unwrap();
        let planned: Vec<_> = plan
            .steps
            .iter()
            .filter_map(|s| match s {
                Step::Write { field, .. } => Some(field.name),
                _ => None,
            })
            .collect();
        assert_eq!(names, planned);
        // integration comes after the frame rate
        let pix = names.iter().position(|n| *n == "pix_cnt_max").unwrap();
        let intg = names.iter().position(|n| *n == "intg_duty_cycle").unwrap();
        assert!(intg > pix);
    }

    #[test]
    fn unsafe_requests_are_clamped_and_reported() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        let cfg = BoardConfig {
            integration_percent: 80.0,
            ..BoardConfig::default()
        };
        let report = configure(&mut bus, &cfg).unwrap();
        let fields: Vec<_> = report.clamps.iter().map(|c| c.field).collect();
        assert_eq!(fields, vec!["intg_duty_cycle"]);
        assert_eq!(report.clamps[0].requested, 51);
        assert_eq!(report.clamps[0].actual, 20);
        let regs = &bus.transport().registers;
        assert_eq!(field::INTG_DUTY_CYCLE.extract(regs[&0x5C4C]), 20);
    }

    #[test]
    fn bad_config_is_rejected_before_any_transfer() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        for cfg in [
            BoardConfig {
                quads: 5,
                ..Default::default()
            },
            BoardConfig {
                frame_rate_hz: f64::NAN,
                ..Default::default()
            },
            BoardConfig {
                modulation_hz: 2e6,
                ..Default::default()
            },
            // below the 22-bit pix_cnt_max and above the output port
            BoardConfig {
                frame_rate_hz: 1.0,
                ..Default::default()
            },
            BoardConfig {
                frame_rate_hz: 60.0,
                ..Default::default()
            },
            BoardConfig {
                roi: Roi {
                    x: 8,
                    y: 0,
                    width: 64,
                    height: 10,
                },
                ..Default::default()
            },
        ] {
            assert!(matches!(
                configure(&mut bus, &cfg),
                Err(ConfigError::OutOfRange(_))
            ));
        }
        assert!(bus.transport().log.is_empty());
    }
}
