//! The packed pixel formats a view is published in.

/// Pixel formats of a published view or data stream.
///
/// * `Grey`: 8-bit luma (`GREY`).
/// * `Y16`: 16-bit little-endian luma (`Y16 `). Signed difference images are
///   offset to unsigned: `y16 = clamp(round(dn) + 32768, 0, 65535)`, so
///   0 DN (no difference) is 32768 and the sign is `y16 >= 32768`.
/// * `Yuyv`: packed 4:2:2, BT.601 limited range (browser-safe).
/// * `Rgb24`: packed R, G, B bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    Grey,
    Y16,
    Yuyv,
    Rgb24,
}

/// Offset added to signed DN to store them in Y16 (see [`PixelFormat::Y16`]).
pub const Y16_ZERO_DN: i32 = 32768;

impl PixelFormat {
    /// The V4L2 fourcc code.
    pub fn fourcc(self) -> u32 {
        let code: &[u8; 4] = match self {
            Self::Grey => b"GREY",
            Self::Y16 => b"Y16 ",
            Self::Yuyv => b"YUYV",
            Self::Rgb24 => b"RGB3",
        };
        u32::from_le_bytes(*code)
    }

    /// Inverse of [`fourcc`](Self::fourcc).
    pub fn from_fourcc(code: u32) -> Option<Self> {
        [Self::Grey, Self::Y16, Self::Yuyv, Self::Rgb24]
            .into_iter()
            .find(|f| f.fourcc() == code)
    }

    /// Bytes per pixel (YUYV: 2 per pixel on average).
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Grey => 1,
            Self::Y16 | Self::Yuyv => 2,
            Self::Rgb24 => 3,
        }
    }

    /// ffmpeg's name for the same layout (for tests and tools).
    pub fn ffmpeg_name(self) -> &'static str {
        match self {
            Self::Grey => "gray",
            Self::Y16 => "gray16le",
            Self::Yuyv => "yuyv422",
            Self::Rgb24 => "rgb24",
        }
    }
}

impl std::fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let code = self.fourcc().to_le_bytes();
        write!(f, "{}", String::from_utf8_lossy(&code).trim_end())
    }
}
