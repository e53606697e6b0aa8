//! The light driver `[lights] driver` names.

use std::time::Duration;

use super::board_output::BoardOutput;
use super::gpio::GpioEnables;
use super::scpi::{FunctionGenerator, TcpPort, UsbtmcPort, SCPI_TCP_PORT};
use super::{LightError, LightSource};
use crate::config::LightsConfig;

/// Driver names accepted in `[lights] driver`.
pub const DRIVERS: &[&str] = &["none", "board", "scpi-tcp", "usbtmc", "gpio"];

/// How long an instrument may take to connect or answer.
pub const INSTRUMENT_TIMEOUT: Duration = Duration::from_secs(2);

/// Why the configured driver could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum SelectError {
    #[error("unknown light driver '{0}': use one of none, board, scpi-tcp, usbtmc, gpio")]
    Unknown(String),
    #[error("[lights] driver = \"scpi-tcp\" needs address = \"host:port\"")]
    NoAddress,
    #[error(transparent)]
    Light(#[from] LightError),
}

/// Opens the driver; `None` for "none" (nothing to drive).
pub fn open(c: &LightsConfig) -> Result<Option<Box<dyn LightSource>>, SelectError> {
    Ok(match c.driver.as_str() {
        "none" => None,
        "board" => Some(Box::new(BoardOutput::default())),
        "scpi-tcp" => {
            if c.address.is_empty() {
                return Err(SelectError::NoAddress);
            }
            let addr = if c.address.contains(':') {
                c.address.clone()
            } else {
                format!("{}:{SCPI_TCP_PORT}", c.address)
            };
            let port = TcpPort::connect(addr.as_str(), INSTRUMENT_TIMEOUT)?;
            Some(Box::new(FunctionGenerator::new(port)?))
        }
        "usbtmc" => {
            let port = UsbtmcPort::open(&c.device)?;
            Some(Box::new(FunctionGenerator::new(port)?))
        }
        "gpio" => Some(Box::new(GpioEnables::open(
            &c.gpio_chip,
            c.ls1_line,
            c.ls2_line,
        )?)),
        other => return Err(SelectError::Unknown(other.into())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_missing_settings_give_clear_errors() {
        let mut c = LightsConfig::default();
        assert!(open(&c).unwrap().is_none());
        c.driver = "laser".into();
        assert!(matches!(open(&c), Err(SelectError::Unknown(_))));
        c.driver = "scpi-tcp".into();
        assert!(matches!(open(&c), Err(SelectError::NoAddress)));
        c.driver = "board".into();
        assert!(open(&c).unwrap().is_some());
    }
}
