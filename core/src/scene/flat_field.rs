//! A uniform target: the same LS1 and LS2 rate everywhere.

use super::{Radiance, Scene};
use crate::image::Image;

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

impl Scene for FlatField {
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
        out.ls1 = Some(Image::filled(w, h, self.ls1_electrons_per_us));
        out.ls2 = Some(Image::filled(w, h, self.ls2_electrons_per_us));
    }
}
