//! Birefringent spatial gradient (section 5.4, Fig. crystal_sketch): a
//! polarization-preserving resolution chart under two orthogonally polarized
//! sources, a birefringent crystal on the sensor displacing one polarization
//! by about one pixel. I+ is the chart, I- the same chart shifted by
//! `displacement_px` along x, so I+ - I- is a horizontal gradient: uniform
//! areas cancel, edges give opposite signs on opposite sides.

use super::{Radiance, Scene};
use crate::image::Image;

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

impl Scene for BirefringentChart {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn is_static(&self) -> bool {
        true
    }

    fn render(&self, _t_us: f64, out: &mut Radiance) {
        let (w, h) = (self.width, self.height);
        let mut plus = Image::new(w, h);
        let mut minus = Image::new(w, h);
        let s = self.source_electrons_per_us;
        for y in 0..h {
            let yc = y as f32 + 0.5;
            for x in 0..w {
                let xc = x as f32 + 0.5;
                let i = plus.index(x, y);
                plus.data[i] = s * self.reflectance(xc, yc);
                minus.data[i] = s * self.reflectance(xc - self.displacement_px, yc);
            }
        }
        out.ls1 = Some(plus);
        out.ls2 = Some(minus);
        out.ambient = None;
    }
}
