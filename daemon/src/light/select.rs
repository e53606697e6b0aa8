//! The light driver `[lights] driver` names.

use std::time::Duration;

use super::board_output::BoardOutput;
use super::gpio::GpioEnables;
use super::scpi::{FunctionGenerator, TcpPort, UsbtmcPort};
use super::{LightError, LightSource};
use sdi_config::{LightDriver, LightsSection};

/// How long an instrument may take to connect or answer.
pub const INSTRUMENT_TIMEOUT: Duration = Duration::from_secs(2);

/// Why the configured driver could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum SelectError {
    #[error("[lights] driver = \"scpi-tcp\" needs address = \"host:port\"")]
    NoAddress,
    #[error(transparent)]
    Light(#[from] LightError),
}

/// Opens the driver of a validated `[lights]` section (`Config::validate`
/// added the default port to a bare address); `None` for "none".
pub fn open(c: &LightsSection) -> Result<Option<Box<dyn LightSource>>, SelectError> {
    Ok(match c.driver {
        LightDriver::None => None,
        LightDriver::Board => Some(Box::new(BoardOutput::default())),
        LightDriver::ScpiTcp => {
            if c.address.is_empty() {
                return Err(SelectError::NoAddress);
            }
            let port = TcpPort::connect(c.address.as_str(), INSTRUMENT_TIMEOUT)?;
            Some(Box::new(FunctionGenerator::new(port)?))
        }
        LightDriver::Usbtmc => {
            let port = UsbtmcPort::open(&c.device)?;
            Some(Box::new(FunctionGenerator::new(port)?))
        }
        LightDriver::Gpio => Some(Box::new(GpioEnables::open(
            &c.gpio_chip,
            c.ls1_line,
            c.ls2_line,
        )?)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_missing_settings_give_clear_errors() {
        let mut c = LightsSection::default();
        assert!(open(&c).unwrap().is_none());
        // An unknown driver name does not reach here: the file refuses it.
        assert!("laser".parse::<LightDriver>().is_err());
        c.driver = LightDriver::ScpiTcp;
        assert!(matches!(open(&c), Err(SelectError::NoAddress)));
        c.driver = LightDriver::Board;
        assert!(open(&c).unwrap().is_some());
    }
}
