//! Depth-edge scene (section 5.3, Fig. dir_plants): fronto-parallel objects at
//! several depths in front of a wall, lit by two identical point sources on
//! opposite sides of the lens, LS1 left (or above) and LS2 right (or below).
//!
//! Only geometry and cast shadows are modelled (no spectra, no shading
//! differences): a pixel seeing a surface at depth z_p is shadowed from a
//! source at lateral offset s (mm, in the camera plane) when an object at
//! depth z_o < z_p covers the image point p + f s (1/z_o - 1/z_p), f being
//! the focal length in pixels. Shadows therefore lie on the side of an object
//! away from the source that casts them, with a width f s (1/z_o - 1/z_p) set
//! by the source spacing: left of an object only LS1 lights the wall (positive
//! difference), right of it only LS2 (negative).

use serde::{Deserialize, Serialize};

use super::StillScene;

/// Where the two sources sit relative to the lens.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SourcePlacement {
    /// LS1 left, LS2 right: edges across x (vertical edges light up).
    Horizontal,
    /// LS1 above, LS2 below: edges across y.
    Vertical,
}

/// A fronto-parallel object: a rectangle or a disc, in fractions of the frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// (u0, v0, u1, v1): corners as fractions of width and height.
    Rect(f32, f32, f32, f32),
    /// (u, v, r): centre as fractions of width/height, radius as a fraction of height.
    Disc(f32, f32, f32),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Object {
    pub shape: Shape,
    pub depth_mm: f32,
    pub albedo: f32,
}

/// Distance of the wall behind the objects.
pub const WALL_DEPTH_MM: f32 = 1500.0;
pub const WALL_ALBEDO: f32 = 0.5;
/// Depth at which a surface of albedo 1 collects the full source rate.
const REFERENCE_DEPTH_MM: f32 = 1000.0;

/// The objects, nearest last is not required: depth decides occlusion.
pub const OBJECTS: [Object; 3] = [
    Object {
        shape: Shape::Rect(0.15, 0.2, 0.35, 0.75),
        depth_mm: 700.0,
        albedo: 0.7,
    },
    Object {
        shape: Shape::Disc(0.6, 0.45, 0.17),
        depth_mm: 1000.0,
        albedo: 0.6,
    },
    Object {
        shape: Shape::Rect(0.76, 0.55, 0.86, 0.9),
        depth_mm: 500.0,
        albedo: 0.8,
    },
];

pub struct DepthEdgeScene {
    width: usize,
    height: usize,
    source_spacing_mm: f32,
    placement: SourcePlacement,
    source_electrons_per_us: f32,
}

impl DepthEdgeScene {
    pub fn new(
        width: usize,
        height: usize,
        source_spacing_mm: f32,
        placement: SourcePlacement,
        source_electrons_per_us: f32,
    ) -> Self {
        Self {
            width,
            height,
            source_spacing_mm,
            placement,
            source_electrons_per_us,
        }
    }

    /// Focal length in pixels: a 60 degree horizontal field of view.
    pub fn focal_px(&self) -> f32 {
        0.866 * self.width as f32
    }

    fn contains(&self, shape: Shape, x: f32, y: f32) -> bool {
        let (w, h) = (self.width as f32, self.height as f32);
        match shape {
            Shape::Rect(u0, v0, u1, v1) => x >= u0 * w && x < u1 * w && y >= v0 * h && y < v1 * h,
            Shape::Disc(u, v, r) => {
                let (dx, dy, rr) = (x - u * w, y - v * h, r * h);
                dx * dx + dy * dy < rr * rr
            }
        }
    }

    /// Depth and albedo of the surface seen at image point (x, y).
    pub fn surface_at(&self, x: f32, y: f32) -> (f32, f32) {
        OBJECTS
            .iter()
            .filter(|o| self.contains(o.shape, x, y))
            .min_by(|a, b| a.depth_mm.total_cmp(&b.depth_mm))
            .map_or((WALL_DEPTH_MM, WALL_ALBEDO), |o| (o.depth_mm, o.albedo))
    }

    /// Whether the surface seen at pixel (x, y) is lit by (LS1, LS2).
    pub fn lit_by(&self, x: usize, y: usize) -> (bool, bool) {
        let (xc, yc) = (x as f32 + 0.5, y as f32 + 0.5);
        let (z_p, _) = self.surface_at(xc, yc);
        let half = 0.5 * self.source_spacing_mm;
        let lit = |s_mm: f32| {
            !OBJECTS.iter().any(|o| {
                if o.depth_mm >= z_p {
                    return false;
                }
                let shift = self.focal_px() * s_mm * (1.0 / o.depth_mm - 1.0 / z_p);
                let (sx, sy) = match self.placement {
                    SourcePlacement::Horizontal => (xc + shift, yc),
                    SourcePlacement::Vertical => (xc, yc + shift),
                };
                self.contains(o.shape, sx, sy)
            })
        };
        (lit(-half), lit(half))
    }
}

impl StillScene for DepthEdgeScene {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn rates_at(&self, x: usize, y: usize) -> (f32, f32) {
        let (z, albedo) = self.surface_at(x as f32 + 0.5, y as f32 + 0.5);
        let falloff = (REFERENCE_DEPTH_MM / z).powi(2);
        let rate = self.source_electrons_per_us * albedo * falloff;
        let (l1, l2) = self.lit_by(x, y);
        (if l1 { rate } else { 0.0 }, if l2 { rate } else { 0.0 })
    }

    fn depth_at(&self, x: usize, y: usize) -> Option<f32> {
        Some(self.surface_at(x as f32 + 0.5, y as f32 + 0.5).0 / 1000.0)
    }
}
