//! Dark frame and fixed-pattern map from N frames with both sources off.

use super::CalibrationError;
use crate::dark_frame::DarkAccumulator;
use crate::frame::Frame;
use crate::image::{Image, SizeMismatch};

/// Per-pixel dark level and its temporal noise.
#[derive(Debug, Clone, PartialEq)]
pub struct DarkCalibration {
    /// Mean dark value per pixel (black level + fixed pattern), DN.
    pub dark_dn: Image<f32>,
    /// Spatial standard deviation of `dark_dn` about its mean: the fixed-pattern noise, DN.
    pub fixed_pattern_sigma_dn: f64,
    /// Spatial mean of the per-pixel temporal variance: rho^2 sigma_read^2 seen in the dark, DN^2.
    pub read_variance_dn2: f64,
    /// Standard error of `read_variance_dn2`, DN^2.
    pub read_variance_se_dn2: f64,
    pub frames: usize,
}

impl DarkCalibration {
    /// Averages `frames` (N >= 2). Saturated or non-finite samples are skipped;
    /// pixels left with fewer than two samples get the image's median-free
    /// fallback of the global mean and do not enter the noise figures.
    pub fn from_frames<'a>(
        frames: impl IntoIterator<Item = &'a Frame>,
    ) -> Result<Self, CalibrationError> {
        let mut acc: Option<DarkAccumulator> = None;
        for f in frames {
            let a = acc.get_or_insert_with(|| DarkAccumulator::new(f.width(), f.height()));
            a.push(f)?;
        }
        match acc {
            Some(acc) => Self::from_accumulator(&acc),
            None => Err(CalibrationError::TooFew {
                what: "dark frames",
                needed: 2,
                got: 0,
            }),
        }
    }

    /// The same from frames already summed (N >= 2), so a caller can stream
    /// them through one buffer.
    pub fn from_accumulator(acc: &DarkAccumulator) -> Result<Self, CalibrationError> {
        if acc.frames() < 2 {
            return Err(CalibrationError::TooFew {
                what: "dark frames",
                needed: 2,
                got: acc.frames() as usize,
            });
        }
        let (width, height) = acc.size();
        // Pixels with two or more valid samples, with their mean and variance.
        let good: Vec<(usize, f64, f64)> = (0..width * height)
            .filter_map(|i| {
                let var = acc.pixel_variance_dn2(i)?;
                Some((i, acc.pixel_mean_dn(i), var))
            })
            .collect();
        if good.is_empty() {
            return Err(CalibrationError::TooFew {
                what: "usable dark pixels",
                needed: 1,
                got: 0,
            });
        }
        let k = good.len() as f64;
        let mean = good.iter().map(|&(_, m, _)| m).sum::<f64>() / k;
        let fpn_var = good
            .iter()
            .map(|&(_, m, _)| (m - mean).powi(2))
            .sum::<f64>()
            / (k - 1.0).max(1.0);
        let read = good.iter().map(|&(_, _, v)| v).sum::<f64>() / k;
        let read_spread = good
            .iter()
            .map(|&(_, _, v)| (v - read).powi(2))
            .sum::<f64>()
            / (k - 1.0).max(1.0);
        let dark_dn = Image {
            width,
            height,
            data: (0..width * height)
                .map(|i| {
                    if acc.samples(i) >= 2 {
                        acc.pixel_mean_dn(i) as f32
                    } else {
                        mean as f32
                    }
                })
                .collect(),
        };
        // The per-pixel temporal variance also contains the (temporal) mean's
        // noise, sigma^2/N, in the spatial spread of the dark map: remove it.
        let fpn_var = (fpn_var - read / f64::from(acc.frames())).max(0.0);
        Ok(Self {
            dark_dn,
            fixed_pattern_sigma_dn: fpn_var.sqrt(),
            read_variance_dn2: read,
            read_variance_se_dn2: (read_spread / k).sqrt(),
            frames: acc.frames() as usize,
        })
    }

    /// Subtracts the dark frame in place (the paper subtracts the average of
    /// 100 dark frames before separating).
    pub fn subtract(&self, frame: &mut Frame) -> Result<(), CalibrationError> {
        SizeMismatch::check(
            (self.dark_dn.width, self.dark_dn.height),
            (frame.width(), frame.height()),
        )?;
        for (v, d) in frame.dn.data.iter_mut().zip(&self.dark_dn.data) {
            *v -= d;
        }
        Ok(())
    }
}
