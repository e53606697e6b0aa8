//! The board's own illumination output (stock-board variant).
//!
//! The OPT8241-CDK drives its illumination from the sensor's modulation; in
//! the stock-board variant of the paper's appendix LS1 is one of the board's
//! IR sources and LS2 a second one on an extended ribbon cable with reversed
//! polarity, so LS1 always follows f and LS2 not-f at the board's own
//! modulation frequency (>= 9.4 MHz with 4 quads). Nothing else is possible
//! without rewiring: other drives are refused rather than faked.

use sdi_core::modulation::SourceDrive;

use super::{LightDrive, LightError, LightSource};

#[derive(Debug, Default)]
pub struct BoardOutput {
    pub last: Option<LightDrive>,
}

impl LightSource for BoardOutput {
    fn describe(&self) -> String {
        "OPT8241-CDK illumination output (LS2 reversed polarity)".into()
    }

    fn apply(&mut self, drive: &LightDrive) -> Result<(), LightError> {
        drive.validate()?;
        match (drive.ls1, drive.ls2) {
            (SourceDrive::Modulated, SourceDrive::Inverted) if (drive.duty - 0.5).abs() < 1e-9 => {
                self.last = Some(*drive);
                Ok(())
            }
            (ls1, ls2) => Err(LightError::Unsupported {
                rig: "board illumination output",
                ls1,
                ls2,
                why: "its sources follow the sensor modulation (LS1 = f, LS2 = not-f, 50 % duty); use a function generator or GPIO enables for other drives",
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_core::modulation::Illumination;

    #[test]
    fn only_snapshot_drive_is_possible() {
        let mut b = BoardOutput::default();
        b.apply(&LightDrive::from_illumination(&Illumination::snapshot(
            12e6,
        )))
        .unwrap();
        let e = b.apply(&LightDrive::off(12e6)).unwrap_err();
        assert!(e.to_string().contains("function generator"), "{e}");
    }
}
