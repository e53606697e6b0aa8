//! Polarization-difference scene (section 5.1, Fig. pol_sketch): two identical
//! sources behind crossed linear polarizers, an analyzer on the lens parallel
//! to LS1's polarizer.
//!
//! Per pixel a material has a direct (single-scattering, polarization
//! preserving) part and a multiply scattered, fully depolarized part "rot",
//! both as fractions of one source's light. With I_par^rot = I_perp^rot:
//! I+ = I_par^direct + I_par^rot / 2, I- = I_perp^rot / 2, so
//! I+ - I- = I^direct. Only that is modelled: no Mueller calculus, no spectra.

use super::StillScene;

/// Which object a pixel sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Region {
    /// Matte wall behind everything: depolarizing.
    Wall,
    /// A wax-like block: subsurface scattering only, purely depolarizing.
    DepolarizingBlock,
    /// A glossy sphere: diffuse body (depolarizing) plus a specular highlight.
    GlossySphere,
    /// A polished metal plate: mostly polarization preserving.
    MetalPlate,
}

/// Direct and depolarized reflectance of one pixel (fractions of one source).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Components {
    pub direct: f32,
    pub rot: f32,
}

pub struct PolarizationScene {
    width: usize,
    height: usize,
    source_electrons_per_us: f32,
}

impl PolarizationScene {
    pub fn new(width: usize, height: usize, source_electrons_per_us: f32) -> Self {
        Self {
            width,
            height,
            source_electrons_per_us,
        }
    }

    /// Object and reflectance components at pixel (x, y).
    pub fn components_at(&self, x: usize, y: usize) -> (Region, Components) {
        let (w, h) = (self.width as f32, self.height as f32);
        let (u, v) = ((x as f32 + 0.5) / w, (y as f32 + 0.5) / h);
        if (0.06..0.30).contains(&u) && (0.2..0.8).contains(&v) {
            let c = Components {
                direct: 0.0,
                rot: 0.8,
            };
            return (Region::DepolarizingBlock, c);
        }
        if (0.72..0.94).contains(&u) && (0.25..0.75).contains(&v) {
            // Brushed metal: a soft gradient of the specular part.
            let c = Components {
                direct: 0.5 + 0.3 * (v - 0.25),
                rot: 0.05,
            };
            return (Region::MetalPlate, c);
        }
        // Sphere centred in the frame, radius 0.3 of the height, in pixels.
        let r = 0.3 * h;
        let (dx, dy) = (
            (x as f32 + 0.5 - 0.5 * w) / r,
            (y as f32 + 0.5 - 0.5 * h) / r,
        );
        let d2 = dx * dx + dy * dy;
        if d2 < 1.0 {
            let nz = (1.0 - d2).sqrt();
            // Blinn-Phong highlight for a light up and left of the camera.
            let (lx, ly, lz) = (-0.3f32, -0.3f32, 0.905f32);
            let (hx, hy, hz) = (lx, ly, lz + 1.0);
            let hn = (hx * hx + hy * hy + hz * hz).sqrt();
            let n_dot_h = ((dx * hx + dy * hy + nz * hz) / hn).max(0.0);
            let c = Components {
                direct: 0.9 * n_dot_h.powi(64),
                rot: 0.6 * nz,
            };
            return (Region::GlossySphere, c);
        }
        (
            Region::Wall,
            Components {
                direct: 0.0,
                rot: 0.3,
            },
        )
    }
}

impl StillScene for PolarizationScene {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn rates_at(&self, x: usize, y: usize) -> (f32, f32) {
        let (_, c) = self.components_at(x, y);
        let s = self.source_electrons_per_us;
        // Section 5.1: I+ = direct + rot/2, I- = rot/2.
        (s * (c.direct + 0.5 * c.rot), s * 0.5 * c.rot)
    }
}
