//! A uniform target: the same LS1 and LS2 rate everywhere.

use super::StillScene;

pub struct FlatField {
    width: usize,
    height: usize,
    ls1_electrons_per_us: f32,
    ls2_electrons_per_us: f32,
}

impl FlatField {
    pub fn new(
        width: usize,
        height: usize,
        ls1_electrons_per_us: f32,
        ls2_electrons_per_us: f32,
    ) -> Self {
        Self {
            width,
            height,
            ls1_electrons_per_us,
            ls2_electrons_per_us,
        }
    }
}

impl StillScene for FlatField {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn rates_at(&self, _x: usize, _y: usize) -> (f32, f32) {
        (self.ls1_electrons_per_us, self.ls2_electrons_per_us)
    }
}
