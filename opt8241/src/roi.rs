//! The region of interest: which pixels the board reads out.

/// Region of interest: columns in steps of 16 (SDK `_allowedROI`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Roi {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl Roi {
    pub const FULL: Roi = Roi {
        x: 0,
        y: 0,
        width: 320,
        height: 240,
    };

    pub const fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }
}
