//! A 24-patch colour chart under a red LS1 and a blue LS2 (section 5.2,
//! bipolar colour): reddish patches give positive differences, bluish ones
//! negative, the grey row about zero.
//!
//! Only what the mode needs: per patch one reflectance under the red LEDs and
//! one under the blue LEDs, no spectra. The values are the linearized red and
//! blue channels of the standard ColorChecker sRGB patch colours, a stand-in
//! for the patch reflectance in those two narrow LED bands.

use super::StillScene;

/// Patch columns and rows (the ColorChecker's 6 x 4 layout).
pub const COLUMNS: usize = 6;
pub const ROWS: usize = 4;

/// (name, sRGB red, sRGB blue) of the 24 patches, row by row; row 4 is the
/// grey scale (white to black).
pub const PATCHES: [(&str, u8, u8); 24] = [
    ("dark skin", 115, 68),
    ("light skin", 194, 130),
    ("blue sky", 98, 157),
    ("foliage", 87, 67),
    ("blue flower", 133, 177),
    ("bluish green", 103, 170),
    ("orange", 214, 44),
    ("purplish blue", 80, 166),
    ("moderate red", 193, 99),
    ("purple", 94, 108),
    ("yellow green", 157, 64),
    ("orange yellow", 224, 46),
    ("blue", 56, 150),
    ("green", 70, 73),
    ("red", 175, 60),
    ("yellow", 231, 31),
    ("magenta", 187, 149),
    ("cyan", 8, 161),
    ("white", 243, 242),
    ("neutral 8", 200, 200),
    ("neutral 6.5", 160, 160),
    ("neutral 5", 122, 121),
    ("neutral 3.5", 85, 85),
    ("black", 52, 52),
];

/// Reflectance of the chart's black surround under either source.
pub const SURROUND_REFLECTANCE: f32 = 0.03;

/// sRGB 8-bit value to linear reflectance in [0, 1].
fn linear(v: u8) -> f32 {
    let c = v as f32 / 255.0;
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// (red, blue) reflectance of patch `i` (0..24).
pub fn patch_reflectance(i: usize) -> (f32, f32) {
    let (_, r, b) = PATCHES[i];
    (linear(r), linear(b))
}

/// The chart filling the frame: patches on a black surround.
pub struct ColourChart {
    width: usize,
    height: usize,
    red_led_electrons_per_us: f32,
    blue_led_electrons_per_us: f32,
}

impl ColourChart {
    pub fn new(
        width: usize,
        height: usize,
        red_led_electrons_per_us: f32,
        blue_led_electrons_per_us: f32,
    ) -> Self {
        Self {
            width,
            height,
            red_led_electrons_per_us,
            blue_led_electrons_per_us,
        }
    }

    /// The patch index (0..24) at pixel (x, y), or `None` on the surround.
    /// Each patch is the middle 70 % of its cell.
    pub fn patch_at(&self, x: usize, y: usize) -> Option<usize> {
        let cx = (x as f64 + 0.5) * COLUMNS as f64 / self.width as f64;
        let cy = (y as f64 + 0.5) * ROWS as f64 / self.height as f64;
        let (col, row) = (cx.floor(), cy.floor());
        let inside = |f: f64| (0.15..0.85).contains(&f);
        (inside(cx - col) && inside(cy - row)).then(|| row as usize * COLUMNS + col as usize)
    }
}

impl StillScene for ColourChart {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn rates_at(&self, x: usize, y: usize) -> (f32, f32) {
        let (r, b) = self.patch_at(x, y).map_or(
            (SURROUND_REFLECTANCE, SURROUND_REFLECTANCE),
            patch_reflectance,
        );
        (
            r * self.red_led_electrons_per_us,
            b * self.blue_led_electrons_per_us,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_row_is_neutral_and_primaries_are_bipolar() {
        for (i, patch) in PATCHES.iter().enumerate().skip(18) {
            let (r, b) = patch_reflectance(i);
            assert!((r - b).abs() < 0.02 * r.max(b), "{}", patch.0);
        }
        let (r, b) = patch_reflectance(14); // red
        assert!(r > 4.0 * b);
        let (r, b) = patch_reflectance(12); // blue
        assert!(b > 4.0 * r);
    }

    #[test]
    fn every_patch_is_visible() {
        let c = ColourChart::new(320, 240, 1.0, 1.0);
        let mut seen = [false; 24];
        for y in 0..240 {
            for x in 0..320 {
                if let Some(p) = c.patch_at(x, y) {
                    seen[p] = true;
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
    }
}
