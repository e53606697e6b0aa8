//! The fixed geometry of a loopback node; its pixel formats are the view's
//! ([`sdi_core::view::PixelFormat`]), which renders the bytes it publishes.

pub use sdi_core::view::{PixelFormat, Y16_ZERO_DN};

/// How frames reach the driver.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum IoMethod {
    /// mmap output streaming (QBUF with exact bytesused and timestamp);
    /// falls back to `Write` when the driver refuses buffers.
    #[default]
    Mmap,
    /// Plain `write()` of whole frames.
    Write,
}

/// The fixed geometry and rate of one loopback node. All modes render into
/// one geometry: the module cannot change resolution under open readers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopbackFormat {
    pub width: u32,
    pub height: u32,
    pub format: PixelFormat,
    pub fps: u32,
    pub io: IoMethod,
}

impl LoopbackFormat {
    /// Browser-safe view profile: YUYV 640x480 (a size Firefox lists).
    pub fn view(fps: u32) -> Self {
        Self {
            width: 640,
            height: 480,
            format: PixelFormat::Yuyv,
            fps,
            io: IoMethod::Mmap,
        }
    }

    /// Raw data profile: Y16 at the sensor's size.
    pub fn raw(width: u32, height: u32, fps: u32) -> Self {
        Self {
            width,
            height,
            format: PixelFormat::Y16,
            fps,
            io: IoMethod::Mmap,
        }
    }

    /// Bytes per line of the tightly packed output.
    pub fn bytes_per_line(&self) -> usize {
        self.width as usize * self.format.bytes_per_pixel()
    }

    /// Bytes of one frame (the exact `bytesused`).
    pub fn frame_bytes(&self) -> usize {
        self.bytes_per_line() * self.height as usize
    }

    /// Checks the geometry before any ioctl.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 || self.fps == 0 {
            return Err(format!("width, height and fps must be > 0 (got {self})"));
        }
        if self.format == PixelFormat::Yuyv && self.width & 1 == 1 {
            return Err(format!("YUYV needs an even width (got {})", self.width));
        }
        if self.width > 8192 || self.height > 8192 {
            return Err(format!("{}x{} exceeds 8192x8192", self.width, self.height));
        }
        Ok(())
    }
}

impl std::fmt::Display for LoopbackFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {}x{} @{} fps",
            self.format, self.width, self.height, self.fps
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourcc_round_trip_and_sizes() {
        for f in [
            PixelFormat::Grey,
            PixelFormat::Y16,
            PixelFormat::Yuyv,
            PixelFormat::Rgb24,
        ] {
            assert_eq!(PixelFormat::from_fourcc(f.fourcc()), Some(f));
        }
        assert_eq!(PixelFormat::Yuyv.fourcc(), 0x5659_5559);
        let c = LoopbackFormat::view(30);
        assert_eq!(c.bytes_per_line(), 1280);
        assert_eq!(c.frame_bytes(), 640 * 480 * 2);
        assert!(LoopbackFormat { width: 641, ..c }.validate().is_err());
        assert!(LoopbackFormat { fps: 0, ..c }.validate().is_err());
        assert_eq!(PixelFormat::Y16.to_string(), "Y16");
    }
}
