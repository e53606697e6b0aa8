//! The board's temperatures and output overflow, read every
//! [`POLL_INTERVAL`] while streaming, and what of them is worth a log line.
//!
//! The SDK refreshes tsensor and tillum every 5 s and calls 0-50 C and
//! 0-40 C valid (`TintinCDKCamera.conf`, `[observed_params]`).
//! op_overflow (0x5C63 [20]) says the output port could not keep up; it
//! stays set until written 0 (OPT9221.dml).

use std::ops::RangeInclusive;
use std::time::Duration;

use crate::protocol::{ProtocolError, RegisterBus, Transport};
use crate::registers::field;

/// How often the board is polled while streaming.
pub const POLL_INTERVAL: Duration = Duration::from_secs(5);
/// tsensor's valid range (SDK `observed_params`), degrees Celsius.
pub const SENSOR_VALID_C: RangeInclusive<i8> = 0..=50;
/// tillum's valid range (SDK `observed_params`), degrees Celsius.
pub const ILLUMINATION_VALID_C: RangeInclusive<i8> = 0..=40;

/// Board temperatures and status flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardStatus {
    pub sensor_celsius: i8,
    pub illumination_celsius: i8,
    pub master_pll_locked: bool,
    pub output_overflow: bool,
}

/// Reads the temperatures and status flags.
pub fn read_status<T: Transport>(bus: &mut RegisterBus<T>) -> Result<BoardStatus, ProtocolError> {
    let status = bus.read_register(field::MASTER_PLL_LOCK.address)?;
    Ok(BoardStatus {
        sensor_celsius: bus.read_field(field::TSENSOR)? as u8 as i8,
        illumination_celsius: bus.read_field(field::TILLUM)? as u8 as i8,
        master_pll_locked: field::MASTER_PLL_LOCK.extract(status) != 0,
        output_overflow: field::OP_OVERFLOW.extract(status) != 0,
    })
}

/// The board's temperatures and output overflows, polled while streaming.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardHealth {
    pub sensor_c: i8,
    pub illumination_c: i8,
    pub output_overflows: u64,
}

/// Reads the status and clears op_overflow when it was set.
pub fn poll<T: Transport>(bus: &mut RegisterBus<T>) -> Result<BoardStatus, ProtocolError> {
    let status = read_status(bus)?;
    if status.output_overflow {
        bus.write_field(field::OP_OVERFLOW, 0)?;
    }
    Ok(status)
}

/// The health after `status`, and the lines to log: a temperature leaving
/// or re-entering its valid range, and every overflow.
pub fn update(previous: Option<BoardHealth>, status: &BoardStatus) -> (BoardHealth, Vec<String>) {
    let overflows = previous.map_or(0, |h| h.output_overflows) + u64::from(status.output_overflow);
    let now = BoardHealth {
        sensor_c: status.sensor_celsius,
        illumination_c: status.illumination_celsius,
        output_overflows: overflows,
    };
    let mut lines = Vec::new();
    let mut watch = |name: &str, was: Option<i8>, is: i8, valid: &RangeInclusive<i8>| {
        let was_ok = was_in_range(was, valid);
        let is_ok = valid.contains(&is);
        if was_ok != is_ok {
            lines.push(if is_ok {
                format!("{name} temperature back in range: {is} C")
            } else {
                format!(
                    "{name} temperature {is} C is outside {}..{} C",
                    valid.start(),
                    valid.end()
                )
            });
        }
    };
    watch(
        "board sensor",
        previous.map(|h| h.sensor_c),
        now.sensor_c,
        &SENSOR_VALID_C,
    );
    watch(
        "illumination",
        previous.map(|h| h.illumination_c),
        now.illumination_c,
        &ILLUMINATION_VALID_C,
    );
    if status.output_overflow {
        lines.push(
            "output overflow (op_overflow): the board's output port could not keep up; frame dropped"
                .into(),
        );
    }
    (now, lines)
}

/// A previous reading counts as in range when there was none.
fn was_in_range(was: Option<i8>, valid: &RangeInclusive<i8>) -> bool {
    was.is_none_or(|t| valid.contains(&t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::tests::FakeBoard;

    fn status(sensor: i8, illumination: i8, overflow: bool) -> BoardStatus {
        BoardStatus {
            sensor_celsius: sensor,
            illumination_celsius: illumination,
            master_pll_locked: true,
            output_overflow: overflow,
        }
    }

    #[test]
    fn logs_only_state_changes() {
        let (h, lines) = update(None, &status(35, 30, false));
        assert!(lines.is_empty(), "{lines:?}");
        let (h, lines) = update(Some(h), &status(36, 31, false));
        assert!(lines.is_empty(), "{lines:?}");
        let (h, lines) = update(Some(h), &status(52, 31, false));
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].contains("outside 0..50"), "{lines:?}");
        let (h, lines) = update(Some(h), &status(53, 31, false));
        assert!(lines.is_empty(), "{lines:?}");
        let (_, lines) = update(Some(h), &status(45, 31, false));
        assert!(lines[0].contains("back in range"), "{lines:?}");
        let (_, lines) = update(None, &status(35, -10, false));
        assert!(lines[0].contains("illumination"), "{lines:?}");
    }

    #[test]
    fn every_overflow_is_counted_and_said() {
        let (h, lines) = update(None, &status(35, 30, true));
        assert_eq!(h.output_overflows, 1);
        assert!(lines[0].contains("frame dropped"));
        let (h, _) = update(Some(h), &status(35, 30, false));
        let (h, _) = update(Some(h), &status(35, 30, true));
        assert_eq!(h.output_overflows, 2);
    }

    #[test]
    fn status_decodes_signed_temperatures() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        bus.transport_mut().registers.insert(0x5C61, 0xF6); // -10 C
        bus.transport_mut().registers.insert(0x5C62, 41);
        bus.transport_mut().registers.insert(0x5C63, 1 << 4);
        let s = read_status(&mut bus).unwrap();
        assert_eq!(s.sensor_celsius, -10);
        assert_eq!(s.illumination_celsius, 41);
        assert!(s.master_pll_locked);
        assert!(!s.output_overflow);
    }
}
