//! Dark ("black") frame: averaged before acquisition and subtracted from every
//! frame to remove the fixed-pattern offset (section 4, measurement procedure).

use crate::frame::Frame;
use crate::image::{Image, SizeMismatch};
use crate::separation::Welford;

/// Summary of a dark-frame capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DarkStats {
    pub frames: u32,
    /// Spatial mean of the per-pixel means, DN (pixels with a valid sample).
    pub mean_dn: f64,
    /// Spatial mean of the per-pixel unbiased temporal variance, DN^2: the
    /// read noise (eq. skellamvar with no light). NaN with fewer than two
    /// valid samples in every pixel (N = 1).
    pub read_noise_variance_dn2: f64,
    /// Spatial standard deviation (1/K) of the per-pixel means, DN: the fixed pattern.
    pub fixed_pattern_sigma_dn: f64,
}

/// Running per-pixel mean and temporal variance of dark frames (LEDs off).
///
/// M1's Welford accumulator ([`Welford`], f64), so thousands of frames at
/// any offset lose nothing to cancellation; samples that are saturated or
/// non-finite are left out of that pixel's statistics. The one dark-frame
/// statistic of the project: the daemon's dark capture, the simulator tools
/// and [`crate::calibration::DarkCalibration`] all use it.
#[derive(Debug, Clone)]
pub struct DarkAccumulator {
    acc: Welford,
    frames: u32,
}

impl DarkAccumulator {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            acc: Welford::new(width, height),
            frames: 0,
        }
    }

    /// Adds one dark frame; a frame of another size is refused.
    pub fn push(&mut self, frame: &Frame) -> Result<(), SizeMismatch> {
        let want = self.acc.size();
        let got = (frame.width(), frame.height());
        SizeMismatch::check(want, got)?;
        // Only an empty (0-pixel) frame is refused by M1: nothing to add then.
        if want.0 * want.1 > 0 {
            self.acc
                .push(frame)
                .map_err(|_| SizeMismatch::new(want, got))?;
        }
        self.frames = self.frames.saturating_add(1);
        Ok(())
    }

    /// Number of frames added so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// (width, height) this accumulator takes.
    pub fn size(&self) -> (usize, usize) {
        self.acc.size()
    }

    /// Valid samples of pixel `i`.
    pub fn samples(&self, i: usize) -> u32 {
        self.acc.samples(i)
    }

    /// Mean of pixel `i`, DN (0 when it never had a valid sample).
    pub fn pixel_mean_dn(&self, i: usize) -> f64 {
        self.acc.pixel_mean_dn(i)
    }

    /// Unbiased temporal variance of pixel `i`, DN^2; `None` below two valid samples.
    pub fn pixel_variance_dn2(&self, i: usize) -> Option<f64> {
        self.acc.pixel_variance_dn2(i)
    }

    fn pixels(&self) -> usize {
        let (w, h) = self.acc.size();
        w * h
    }

    /// The mean dark frame in DN; pixels never valid get 0. `None` before any frame.
    pub fn mean_dn(&self) -> Option<Image<f32>> {
        if self.frames == 0 {
            return None;
        }
        let (w, h) = self.acc.size();
        let data = (0..w * h).map(|i| self.pixel_mean_dn(i) as f32).collect();
        Image::from_vec(w, h, data)
    }

    /// Mean level, read noise and fixed pattern; `None` until a pixel had a
    /// valid sample.
    pub fn stats(&self) -> Option<DarkStats> {
        let valid = || (0..self.pixels()).filter(|&i| self.samples(i) > 0);
        let k = valid().count();
        if k == 0 {
            return None;
        }
        let k = k as f64;
        let mean_dn = valid().map(|i| self.pixel_mean_dn(i)).sum::<f64>() / k;
        let fpn_var = valid()
            .map(|i| (self.pixel_mean_dn(i) - mean_dn).powi(2))
            .sum::<f64>()
            / k;
        let variances: Vec<f64> = (0..self.pixels())
            .filter_map(|i| self.pixel_variance_dn2(i))
            .collect();
        let read_noise_variance_dn2 = if variances.is_empty() {
            f64::NAN
        } else {
            variances.iter().sum::<f64>() / variances.len() as f64
        };
        Some(DarkStats {
            frames: self.frames,
            mean_dn,
            read_noise_variance_dn2,
            fixed_pattern_sigma_dn: fpn_var.sqrt(),
        })
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

    fn frame(dn: &[f32], saturated: &[u8]) -> Frame {
        let mut f = Frame::new(dn.len(), 1);
        f.dn.data = dn.to_vec();
        f.saturated.data = saturated.to_vec();
        f
    }

    #[test]
    fn mean_skips_saturated_and_nan() {
        let mut acc = DarkAccumulator::new(2, 1);
        acc.push(&frame(&[2.0, f32::NAN], &[0, 0])).unwrap();
        acc.push(&frame(&[4.0, 7.0], &[0, 1])).unwrap();
        let m = acc.mean_dn().unwrap();
        assert_eq!(m.data, vec![3.0, 0.0]);
        assert_eq!(acc.frames(), 2);
        assert_eq!((acc.samples(0), acc.samples(1)), (2, 0));
        assert!(acc.push(&Frame::new(3, 1)).is_err());
        // the unusable pixel stays out of the figures
        let s = acc.stats().unwrap();
        assert_eq!(s.mean_dn, 3.0);
        assert_eq!(s.read_noise_variance_dn2, 2.0);
        assert_eq!(s.fixed_pattern_sigma_dn, 0.0);
    }

    #[test]
    fn empty_accumulator_has_no_mean() {
        let acc = DarkAccumulator::new(4, 4);
        assert!(acc.mean_dn().is_none());
        assert!(acc.stats().is_none());
    }

    #[test]
    fn all_invalid_has_a_mean_frame_but_no_stats() {
        let mut acc = DarkAccumulator::new(2, 1);
        acc.push(&frame(&[f32::INFINITY, 9.0], &[0, 1])).unwrap();
        acc.push(&frame(&[f32::NAN, f32::NEG_INFINITY], &[0, 0]))
            .unwrap();
        assert_eq!(acc.mean_dn().unwrap().data, vec![0.0, 0.0]);
        assert!(acc.stats().is_none());
    }

    #[test]
    fn one_frame_has_no_read_noise() {
        let mut acc = DarkAccumulator::new(2, 1);
        acc.push(&frame(&[10.0, 14.0], &[0, 0])).unwrap();
        let s = acc.stats().unwrap();
        assert_eq!(
            (s.frames, s.mean_dn, s.fixed_pattern_sigma_dn),
            (1, 12.0, 2.0)
        );
        assert!(s.read_noise_variance_dn2.is_nan());
        assert_eq!(acc.pixel_variance_dn2(0), None);
    }

    #[test]
    fn one_pixel() {
        let mut acc = DarkAccumulator::new(1, 1);
        for v in [100.0, 102.0, 104.0] {
            acc.push(&frame(&[v], &[0])).unwrap();
        }
        let s = acc.stats().unwrap();
        assert_eq!(s.mean_dn, 102.0);
        assert_eq!(s.read_noise_variance_dn2, 4.0);
        assert_eq!(s.fixed_pattern_sigma_dn, 0.0);
    }

    #[test]
    fn zero_sized_frames_give_no_stats() {
        let mut acc = DarkAccumulator::new(0, 0);
        acc.push(&Frame::new(0, 0)).unwrap();
        assert!(acc.stats().is_none());
    }

    #[test]
    fn large_offset_keeps_the_variance() {
        // 1e7 +- 1 DN (exact in f32): Welford gives the variance to rounding
        let mut acc = DarkAccumulator::new(1, 1);
        for k in 0..1000 {
            let v = 1.0e7 + if k % 2 == 0 { -1.0 } else { 1.0 };
            acc.push(&frame(&[v], &[0])).unwrap();
        }
        let var = acc.pixel_variance_dn2(0).unwrap();
        assert!((var - 1000.0 / 999.0).abs() < 1e-9, "{var}");
    }

    /// The daemon's former sums-and-squares statistics, for comparison.
    fn sums_and_squares(frames: &[Frame]) -> (f64, f64, f64) {
        let px = frames[0].dn.data.len();
        let n = frames.len() as f64;
        let mut sum = vec![0.0f64; px];
        let mut sum_sq = vec![0.0f64; px];
        for f in frames {
            for ((s, q), &v) in sum.iter_mut().zip(&mut sum_sq).zip(&f.dn.data) {
                *s += f64::from(v);
                *q += f64::from(v) * f64::from(v);
            }
        }
        let mean = sum.iter().sum::<f64>() / (n * px as f64);
        let var_t = sum
            .iter()
            .zip(&sum_sq)
            .map(|(s, q)| (q - s * s / n) / (n - 1.0))
            .sum::<f64>()
            / px as f64;
        let var_s = sum.iter().map(|s| (s / n - mean).powi(2)).sum::<f64>() / px as f64;
        (mean, var_t, var_s.sqrt())
    }

    #[test]
    fn agrees_with_sums_and_squares_on_clean_data() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::SmallRng::seed_from_u64(14);
        let (w, h) = (16, 8);
        let offsets: Vec<f32> = (0..w * h).map(|_| rng.random_range(60.0..90.0)).collect();
        let frames: Vec<Frame> = (0..25)
            .map(|_| {
                let mut f = Frame::new(w, h);
                for (v, o) in f.dn.data.iter_mut().zip(&offsets) {
                    *v = (o + rng.random_range(-4.0f32..4.0)).round();
                }
                f
            })
            .collect();
        let mut acc = DarkAccumulator::new(w, h);
        for f in &frames {
            acc.push(f).unwrap();
        }
        let s = acc.stats().unwrap();
        let (mean, var_t, sigma_s) = sums_and_squares(&frames);
        assert_eq!(s.frames, 25);
        assert!(
            (s.mean_dn - mean).abs() < 1e-9 * mean,
            "{} {mean}",
            s.mean_dn
        );
        assert!((s.read_noise_variance_dn2 - var_t).abs() < 1e-9 * var_t);
        assert!((s.fixed_pattern_sigma_dn - sigma_s).abs() < 1e-9 * sigma_s);
    }
}
