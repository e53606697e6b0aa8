//! Dark ("black") frame: averaged before acquisition and subtracted from every
//! frame to remove the fixed-pattern offset (section 4, measurement procedure).

use crate::frame::Frame;
use crate::image::Image;

/// Running per-pixel mean of dark frames (LEDs off).
///
/// Sums in f64 so averaging thousands of frames loses nothing; pixels that
/// are saturated or non-finite in a frame are left out of that pixel's mean.
#[derive(Debug, Clone)]
pub struct DarkFrameAverager {
    width: usize,
    height: usize,
    sum_dn: Vec<f64>,
    count: Vec<u32>,
    frames: u32,
}

impl DarkFrameAverager {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            sum_dn: vec![0.0; width * height],
            count: vec![0; width * height],
            frames: 0,
        }
    }

    /// Adds one dark frame; a frame of another size is refused (returns false).
    pub fn add(&mut self, frame: &Frame) -> bool {
        if frame.width() != self.width || frame.height() != self.height {
            return false;
        }
        let it = self
            .sum_dn
            .iter_mut()
            .zip(self.count.iter_mut())
            .zip(frame.dn.data.iter().zip(&frame.saturated.data));
        for ((sum, n), (&v, &sat)) in it {
            if sat == 0 && v.is_finite() {
                *sum += f64::from(v);
                *n += 1;
            }
        }
        self.frames += 1;
        true
    }

    /// Number of frames added so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The mean dark frame in DN; pixels never valid get 0. `None` before any frame.
    pub fn mean_dn(&self) -> Option<Image<f32>> {
        if self.frames == 0 {
            return None;
        }
        let data = self
            .sum_dn
            .iter()
            .zip(&self.count)
            .map(|(&s, &n)| {
                if n == 0 {
                    0.0
                } else {
                    (s / f64::from(n)) as f32
                }
            })
            .collect();
        Image::from_vec(self.width, self.height, data)
    }
}

/// The subtraction stage: `dn -= dark_dn`, element-wise, in place.
/// Both slices must have the same length (callers check image sizes).
#[inline]
pub fn subtract_dark(dn: &mut [f32], dark_dn: &[f32]) {
    for (v, &d) in dn.iter_mut().zip(dark_dn) {
        *v -= d;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_skips_saturated_and_nan() {
        let mut avg = DarkFrameAverager::new(2, 1);
        let mut f = Frame::new(2, 1);
        f.dn.data = vec![2.0, f32::NAN];
        assert!(avg.add(&f));
        f.dn.data = vec![4.0, 7.0];
        f.saturated.data = vec![0, 1];
        assert!(avg.add(&f));
        let m = avg.mean_dn().unwrap();
        assert_eq!(m.data, vec![3.0, 0.0]);
        assert!(!avg.add(&Frame::new(3, 1)));
    }

    #[test]
    fn empty_averager_has_no_mean() {
        assert!(DarkFrameAverager::new(4, 4).mean_dn().is_none());
    }
}
