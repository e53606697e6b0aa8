//! Dark frame and fixed-pattern map from N frames with both sources off.

use super::CalibrationError;
use crate::frame::Frame;
use crate::image::Image;
use crate::separation::{flags, Welford};

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
        let mut acc: Option<Welford> = None;
        for f in frames {
            let a = acc.get_or_insert_with(|| Welford::new(f.width(), f.height()));
            a.push(f).map_err(|_| CalibrationError::SizeMismatch {
                want_w: 0,
                want_h: 0,
                got_w: f.width(),
                got_h: f.height(),
            })?;
        }
        let got = acc.as_ref().map_or(0, Welford::frames);
        let Some(acc) = acc.filter(|a| a.frames() >= 2) else {
            return Err(CalibrationError::TooFew {
                what: "dark frames",
                needed: 2,
                got,
            });
        };
        let m = acc.moments().map_err(|_| CalibrationError::TooFew {
            what: "dark frames",
            needed: 2,
            got,
        })?;
        let good: Vec<usize> = (0..m.mean_dn.len())
            .filter(|&i| m.flags.data[i] & flags::INSUFFICIENT == 0)
            .collect();
        if good.is_empty() {
            return Err(CalibrationError::TooFew {
                what: "usable dark pixels",
                needed: 1,
                got: 0,
            });
        }
        let k = good.len() as f64;
        let mean = good.iter().map(|&i| m.mean_dn.data[i]).sum::<f64>() / k;
        let fpn_var = good
            .iter()
            .map(|&i| (m.mean_dn.data[i] - mean).powi(2))
            .sum::<f64>()
            / (k - 1.0).max(1.0);
        let read = good.iter().map(|&i| m.variance_dn2.data[i]).sum::<f64>() / k;
        let read_spread = good
            .iter()
            .map(|&i| (m.variance_dn2.data[i] - read).powi(2))
            .sum::<f64>()
            / (k - 1.0).max(1.0);
        let dark_dn = Image {
            width: m.width(),
            height: m.height(),
            data: (0..m.mean_dn.len())
                .map(|i| {
                    if m.flags.data[i] & flags::INSUFFICIENT == 0 {
                        m.mean_dn.data[i] as f32
                    } else {
                        mean as f32
                    }
                })
                .collect(),
        };
        // The per-pixel temporal variance also contains the (temporal) mean's
        // noise, sigma^2/N, in the spatial spread of the dark map: remove it.
        let fpn_var = (fpn_var - read / acc.frames() as f64).max(0.0);
        Ok(Self {
            dark_dn,
            fixed_pattern_sigma_dn: fpn_var.sqrt(),
            read_variance_dn2: read,
            read_variance_se_dn2: (read_spread / k).sqrt(),
            frames: acc.frames(),
        })
    }

    /// Subtracts the dark frame in place (the paper subtracts the average of
    /// 100 dark frames before separating).
    pub fn subtract(&self, frame: &mut Frame) -> Result<(), CalibrationError> {
        if !frame.dn.same_size(&self.dark_dn) {
            return Err(CalibrationError::SizeMismatch {
                want_w: self.dark_dn.width,
                want_h: self.dark_dn.height,
                got_w: frame.width(),
                got_h: frame.height(),
            });
        }
        for (v, d) in frame.dn.data.iter_mut().zip(&self.dark_dn.data) {
            *v -= d;
        }
        Ok(())
    }
}
