//! LED enables on Linux GPIO lines (character device, uAPI v2).
//!
//! Two output lines of one `/dev/gpiochipN` enable the LS1 and LS2 drivers;
//! the modulation itself comes from the board or a generator. The ioctl glue
//! is the only unsafe code here (linux/gpio.h: `GPIO_V2_GET_LINE_IOCTL`,
//! `GPIO_V2_LINE_SET_VALUES_IOCTL`).

use std::fs::{File, OpenOptions};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};

use sdi_core::modulation::SourceDrive;

use super::{LightDrive, LightError, LightSource};

const GPIO_V2_LINES_MAX: usize = 64;
const GPIO_MAX_NAME_SIZE: usize = 32;
const GPIO_V2_LINE_NUM_ATTRS_MAX: usize = 10;
const GPIO_V2_LINE_FLAG_OUTPUT: u64 = 1 << 3;

#[repr(C)]
#[derive(Clone, Copy, Default)]
struct LineAttribute {
    id: u32,
    padding: u32,
    value: u64,
}

#[repr(C)]
#[derive(Clone, Copy, Default)]
struct LineConfigAttribute {
    attr: LineAttribute,
    mask: u64,
}

#[repr(C)]
#[derive(Clone, Copy, Default)]
struct LineConfig {
    flags: u64,
    num_attrs: u32,
    padding: [u32; 5],
    attrs: [LineConfigAttribute; GPIO_V2_LINE_NUM_ATTRS_MAX],
}

#[repr(C)]
struct LineRequest {
    offsets: [u32; GPIO_V2_LINES_MAX],
    consumer: [u8; GPIO_MAX_NAME_SIZE],
    config: LineConfig,
    num_lines: u32,
    event_buffer_size: u32,
    padding: [u32; 5],
    fd: i32,
}

#[repr(C)]
#[derive(Default)]
struct LineValues {
    bits: u64,
    mask: u64,
}

const _: () = assert!(std::mem::size_of::<LineRequest>() == 592);
const _: () = assert!(std::mem::size_of::<LineValues>() == 16);

nix::ioctl_readwrite!(gpio_v2_get_line, 0xB4, 0x07, LineRequest);
nix::ioctl_readwrite!(gpio_v2_line_set_values, 0xB4, 0x0F, LineValues);

/// Requested output lines; values are set together.
pub struct OutputLines {
    chip: PathBuf,
    fd: OwnedFd,
}

impl OutputLines {
    /// Requests `offsets` of `chip` as outputs, initially low.
    pub fn request(chip: &Path, offsets: &[u32], consumer: &str) -> Result<Self, LightError> {
        let err = |source| LightError::Gpio {
            chip: chip.display().to_string(),
            source,
        };
        if offsets.is_empty() || offsets.len() > GPIO_V2_LINES_MAX {
            return Err(err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "1 to 64 lines",
            )));
        }
        let file: File = OpenOptions::new()
            .read(true)
            .write(true)
            .open(chip)
            .map_err(err)?;
        let mut req = LineRequest {
            offsets: [0; GPIO_V2_LINES_MAX],
            consumer: [0; GPIO_MAX_NAME_SIZE],
            config: LineConfig {
                flags: GPIO_V2_LINE_FLAG_OUTPUT,
                ..Default::default()
            },
            num_lines: offsets.len() as u32,
            event_buffer_size: 0,
            padding: [0; 5],
            fd: -1,
        };
        req.offsets[..offsets.len()].copy_from_slice(offsets);
        let name = consumer.as_bytes();
        let n = name.len().min(GPIO_MAX_NAME_SIZE - 1);
        req.consumer[..n].copy_from_slice(&name[..n]);
        // SAFETY: `file` is an open gpiochip descriptor and `req` is a valid,
        // fully initialized `struct gpio_v2_line_request` (size checked above)
        // that lives across the call; the kernel writes only `req.fd`.
        unsafe { gpio_v2_get_line(file.as_raw_fd(), &mut req) }
            .map_err(|e| err(std::io::Error::from(e)))?;
        if req.fd < 0 {
            return Err(err(std::io::Error::other("kernel returned no line fd")));
        }
        // SAFETY: on success the kernel returned a new, owned line-request fd.
        let fd = unsafe { OwnedFd::from_raw_fd(req.fd as RawFd) };
        Ok(Self {
            chip: chip.to_path_buf(),
            fd,
        })
    }

    /// Sets line i (in request order) to bit i of `bits`.
    pub fn set(&self, bits: u64, mask: u64) -> Result<(), LightError> {
        let mut v = LineValues { bits, mask };
        // SAFETY: `self.fd` is a line-request fd from GPIO_V2_GET_LINE_IOCTL
        // and `v` is a valid `struct gpio_v2_line_values` for the call.
        unsafe { gpio_v2_line_set_values(self.fd.as_raw_fd(), &mut v) }.map_err(|e| {
            LightError::Gpio {
                chip: self.chip.display().to_string(),
                source: std::io::Error::from(e),
            }
        })?;
        Ok(())
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
