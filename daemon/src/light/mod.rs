//! What drives the two light sources LS1 and LS2.
//!
//! One trait, several rigs: the board's own illumination output (stock-board
//! variant: LS2 wired with reversed polarity), an SCPI function generator
//! (channel 1 = f, channel 2 = not-f) over TCP or USBTMC, and GPIO lines that
//! enable the LED drivers. Modes ask for a [`LightDrive`] per frame; a rig
//! that cannot do it says so with a typed error.

pub mod board_output;
pub mod driven;
pub mod gpio;
pub mod scpi;
pub mod select;

use sdi_core::modulation::{Illumination, SourceDrive};

/// How LS1 and LS2 should be driven for the next exposures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightDrive {
    pub ls1: SourceDrive,
    pub ls2: SourceDrive,
    /// Square-wave frequency of f(t), Hz.
    pub carrier_hz: f64,
    /// Fraction of the period where f = 1, in (0, 1).
    pub duty: f64,
}

impl LightDrive {
    /// The drive an [`Illumination`] asks for (its first segment's duty;
    /// single-transition patterns are not square waves and keep duty 0.5).
    pub fn from_illumination(ill: &Illumination) -> Self {
        let duty = match ill.modulation.segments.as_slice() {
            [only] if only.duty > 0.0 && only.duty < 1.0 => only.duty,
            _ => 0.5,
        };
        Self {
            ls1: ill.ls1,
            ls2: ill.ls2,
            carrier_hz: ill.modulation.carrier_hz,
            duty,
        }
    }

    /// Both sources dark.
    pub fn off(carrier_hz: f64) -> Self {
        Self {
            ls1: SourceDrive::Off,
            ls2: SourceDrive::Off,
            carrier_hz,
            duty: 0.5,
        }
    }

    /// LEDs only while someone watches the output (when that is known).
    pub fn gated(self, watched: Option<bool>) -> Self {
        match watched {
            Some(false) => Self::off(self.carrier_hz),
            _ => self,
        }
    }

    /// Checks carrier and duty; a drive with both sources off has none to
    /// check (temporal gradient's single-transition pattern has no carrier).
    pub fn validate(&self) -> Result<(), LightError> {
        if self.ls1 == SourceDrive::Off && self.ls2 == SourceDrive::Off {
            return Ok(());
        }
        if !(self.carrier_hz.is_finite() && self.carrier_hz > 0.0) {
            return Err(LightError::OutOfRange {
                name: "carrier_hz",
                value: self.carrier_hz,
                allowed: "> 0 Hz",
            });
        }
        if !(self.duty.is_finite() && self.duty > 0.0 && self.duty < 1.0) {
            return Err(LightError::OutOfRange {
                name: "duty",
                value: self.duty,
                allowed: "(0, 1)",
            });
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum LightError {
    #[error("{rig} cannot drive LS1 = {ls1:?}, LS2 = {ls2:?}: {why}")]
    Unsupported {
        rig: &'static str,
        ls1: SourceDrive,
        ls2: SourceDrive,
        why: &'static str,
    },
    #[error("{name} = {value} is out of range: expected {allowed}")]
    OutOfRange {
        name: &'static str,
        value: f64,
        allowed: &'static str,
    },
    #[error("instrument I/O on {port}: {source}")]
    Io {
        port: String,
        #[source]
        source: std::io::Error,
    },
    #[error("instrument on {port} did not answer {command:?} within {timeout_ms} ms")]
    NoAnswer {
        port: String,
        command: String,
        timeout_ms: u128,
    },
    #[error("instrument on {port} answered {command:?} with malformed {answer:?}")]
    Malformed {
        port: String,
        command: String,
        answer: String,
    },
    #[error("instrument on {port} reports error after {command:?}: {error}")]
    Instrument {
        port: String,
        command: String,
        error: String,
    },
    #[error("GPIO {chip}: {source}")]
    Gpio {
        chip: String,
        #[source]
        source: gpiocdev::Error,
    },
}

/// Anything that drives LS1 and LS2.
pub trait LightSource: Send {
    /// Short description for status output.
    fn describe(&self) -> String;
    /// Drives the sources for the exposures that follow.
    fn apply(&mut self, drive: &LightDrive) -> Result<(), LightError>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drive_from_illumination_and_gating() {
        let d = LightDrive::from_illumination(&Illumination::snapshot(2e6));
        assert_eq!(
            (d.ls1, d.ls2, d.carrier_hz, d.duty),
            (SourceDrive::Modulated, SourceDrive::Inverted, 2e6, 0.5)
        );
        assert!(d.validate().is_ok());
        assert_eq!(d.gated(Some(true)), d);
        assert_eq!(d.gated(None), d);
        let off = d.gated(Some(false));
        assert_eq!((off.ls1, off.ls2), (SourceDrive::Off, SourceDrive::Off));
        let mut dark = LightDrive::off(0.0);
        assert!(dark.validate().is_ok(), "both off needs no carrier");
        dark.ls1 = SourceDrive::Modulated;
        assert!(dark.validate().is_err());
        let bad = LightDrive {
            duty: f64::NAN,
            ..d
        };
        assert!(matches!(
            bad.validate(),
            Err(LightError::OutOfRange { name: "duty", .. })
        ));
    }
}
