//! LED enables on Linux GPIO lines (character device, uAPI v2, through
//! the `gpiocdev` crate).
//!
//! Two output lines of one `/dev/gpiochipN` enable the LS1 and LS2 drivers;
//! the modulation itself comes from the board or a generator.

use std::path::{Path, PathBuf};

use gpiocdev::line::{Offset, Value, Values};
use gpiocdev::Request;
use sdi_core::modulation::SourceDrive;

use super::{LightDrive, LightError, LightSource};

/// Requested output lines; values are set together.
pub struct OutputLines {
    chip: PathBuf,
    offsets: Vec<Offset>,
    request: Request,
}

impl OutputLines {
    /// Requests `offsets` (1 to 64 lines) of `chip` as outputs, initially low.
    pub fn request(chip: &Path, offsets: &[u32], consumer: &str) -> Result<Self, LightError> {
        let request = Request::builder()
            .on_chip(chip)
            .with_consumer(consumer)
            .with_lines(offsets)
            .as_output(Value::Inactive)
            .request()
            .map_err(|source| LightError::Gpio {
                chip: chip.display().to_string(),
                source,
            })?;
        Ok(Self {
            chip: chip.to_path_buf(),
            offsets: offsets.to_vec(),
            request,
        })
    }

    /// Sets line i (in request order) to bit i of `bits`, for the lines
    /// whose bit is set in `mask`.
    pub fn set(&self, bits: u64, mask: u64) -> Result<(), LightError> {
        let mut values = Values::default();
        for (i, &offset) in self.offsets.iter().enumerate().take(64) {
            if mask >> i & 1 == 1 {
                values.set(offset, Value::from(bits >> i & 1 == 1));
            }
        }
        self.request
            .set_values(&values)
            .map_err(|source| LightError::Gpio {
                chip: self.chip.display().to_string(),
                source,
            })
    }
}

/// LS1/LS2 driver enables on two GPIO lines: a source is enabled unless its
/// drive is `Off`.
pub struct GpioEnables {
    lines: OutputLines,
    pub ls1_line: u32,
    pub ls2_line: u32,
}

impl GpioEnables {
    pub fn open(chip: &Path, ls1_line: u32, ls2_line: u32) -> Result<Self, LightError> {
        Ok(Self {
            lines: OutputLines::request(chip, &[ls1_line, ls2_line], "sdid")?,
            ls1_line,
            ls2_line,
        })
    }
}

impl LightSource for GpioEnables {
    fn describe(&self) -> String {
        format!(
            "GPIO enables {} lines {} (LS1) and {} (LS2)",
            self.lines.chip.display(),
            self.ls1_line,
            self.ls2_line
        )
    }

    fn apply(&mut self, drive: &LightDrive) -> Result<(), LightError> {
        let bit = |s: SourceDrive| u64::from(s != SourceDrive::Off);
        self.lines.set(bit(drive.ls1) | (bit(drive.ls2) << 1), 0b11)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_chip_is_a_typed_error() {
        let e = GpioEnables::open(Path::new("/dev/gpiochip-does-not-exist"), 0, 1)
            .err()
            .unwrap();
        assert!(matches!(e, LightError::Gpio { .. }), "{e}");
        assert!(e.to_string().contains("gpiochip-does-not-exist"));
    }
}
