//! Birefringent spatial gradient (section 5.4, Fig. crystal_sketch): a
//! polarization-preserving resolution chart under two orthogonally polarized
//! sources, a birefringent crystal on the sensor displacing one polarization
//! by about one pixel. I+ is the chart, I- the same chart shifted by
//! `displacement_px` along x, so I+ - I- is a horizontal gradient: uniform
//! areas cancel, edges give opposite signs on opposite sides.

use super::StillScene;

/// Reflectance of the chart's background and of its aluminium markers.
pub const BACKGROUND_REFLECTANCE: f32 = 0.15;
pub const MARKER_REFLECTANCE: f32 = 0.85;

pub struct BirefringentChart {
    width: usize,
    height: usize,
    source_electrons_per_us: f32,
    displacement_px: f32,
}

impl BirefringentChart {
    pub fn new(
        width: usize,
        height: usize,
        source_electrons_per_us: f32,
        displacement_px: f32,
    ) -> Self {
        Self {
            width,
            height,
            source_electrons_per_us,
            displacement_px,
        }
    }

    /// Chart reflectance at a continuous position in pixels (x, y measured
    /// from the top-left corner): bars in the upper half, a checkerboard
    /// in the lower half.
    pub fn reflectance(&self, x: f32, y: f32) -> f32 {
        let (u, v) = (x / self.width as f32, y / self.height as f32);
        let marker = if (0.1..0.45).contains(&v) && (0.05..0.95).contains(&u) {
            ((u - 0.05) / 0.06).fract() < 0.5
        } else if (0.55..0.9).contains(&v) && (0.05..0.95).contains(&u) {
            let (cu, cv) = ((u / 0.1).floor() as i64, (v / 0.1).floor() as i64);
            (cu + cv) % 2 == 0
        } else {
            false
        };
        if marker {
            MARKER_REFLECTANCE
        } else {
            BACKGROUND_REFLECTANCE
        }
    }
}

impl StillScene for BirefringentChart {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn rates_at(&self, x: usize, y: usize) -> (f32, f32) {
        let (xc, yc) = (x as f32 + 0.5, y as f32 + 0.5);
        let s = self.source_electrons_per_us;
        (
            s * self.reflectance(xc, yc),
            s * self.reflectance(xc - self.displacement_px, yc),
        )
    }
}
