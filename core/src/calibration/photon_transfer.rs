//! Photon transfer: with one source on at several intensities, the temporal
//! variance grows linearly with the mean (eq. skellamvar with I- = 0):
//! sigma^2 = g |mu| + sigma_read^2, g = rho eta. A weighted straight-line fit
//! gives g and sigma_read^2 with standard errors (the paper's Fig. exp_variance).

use serde::{Deserialize, Serialize};

use super::CalibrationError;
use crate::separation::Moments;

/// One intensity level: spatial averages of per-pixel temporal statistics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PtcPoint {
    /// Mean dark-subtracted signal, DN (sign ignored: LS2 gives negative means).
    pub mean_dn: f64,
    /// Mean per-pixel temporal variance, DN^2.
    pub variance_dn2: f64,
    /// Standard error of `variance_dn2`, DN^2.
    pub variance_se_dn2: f64,
}

impl PtcPoint {
    /// Averages M1 moments (from N frames of a flat, one-source scene) over the
    /// pixels that are not flagged. Per-pixel temporal variance is immune to
    /// fixed-pattern noise; averaging over pixels beats down its noise.
    pub fn from_moments(m: &Moments) -> Result<Self, CalibrationError> {
        let good: Vec<usize> = (0..m.mean_dn.len())
            .filter(|&i| m.flags.data[i] == 0)
            .collect();
        if good.is_empty() {
            return Err(CalibrationError::TooFew {
                what: "unflagged pixels",
                needed: 1,
                got: 0,
            });
        }
        let k = good.len() as f64;
        let mean = good.iter().map(|&i| m.mean_dn.data[i]).sum::<f64>() / k;
        let var = good.iter().map(|&i| m.variance_dn2.data[i]).sum::<f64>() / k;
        let spread = good
            .iter()
            .map(|&i| (m.variance_dn2.data[i] - var).powi(2))
            .sum::<f64>()
            / (k - 1.0).max(1.0);
        let se = if k > 1.0 {
            (spread / k).sqrt()
        } else {
            m.variance_var_dn4.data[good[0]].sqrt()
        };
        Ok(Self {
            mean_dn: mean,
            variance_dn2: var,
            variance_se_dn2: se,
        })
    }
}

/// Result of the straight-line fit sigma^2 = g |mu| + sigma_read^2.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PhotonTransferFit {
    /// g = rho eta, DN per electron.
    pub gain_dn_per_electron: f64,
    pub gain_se: f64,
    /// Intercept: (rho sigma_read)^2, DN^2.
    pub read_variance_dn2: f64,
    pub read_variance_se_dn2: f64,
    /// Reduced chi-square of the fit (about 1 when the model holds).
    pub reduced_chi2: f64,
    pub points: usize,
}

/// Weighted least squares with weights 1 / se^2; parameter errors from the
/// covariance (X^T W X)^-1, inflated by the reduced chi-square when it exceeds 1.
pub fn fit_photon_transfer(points: &[PtcPoint]) -> Result<PhotonTransferFit, CalibrationError> {
    if points.len() < 3 {
        return Err(CalibrationError::TooFew {
            what: "photon-transfer points",
            needed: 3,
            got: points.len(),
        });
    }
    if points.iter().any(|p| {
        !(p.mean_dn.is_finite() && p.variance_dn2.is_finite() && p.variance_se_dn2.is_finite())
    }) {
        return Err(CalibrationError::NonFinite("photon-transfer points"));
    }
    let floor = points
        .iter()
        .map(|p| p.variance_se_dn2)
        .filter(|s| *s > 0.0)
        .fold(f64::INFINITY, f64::min);
    let floor = if floor.is_finite() { floor } else { 1.0 };
    let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in points {
        let w = 1.0 / p.variance_se_dn2.max(floor).powi(2);
        let x = p.mean_dn.abs();
        sw += w;
        sx += w * x;
        sy += w * p.variance_dn2;
        sxx += w * x * x;
        sxy += w * x * p.variance_dn2;
    }
    let det = sw * sxx - sx * sx;
    if det.is_nan() || det <= 1e-12 * sw * sxx {
        return Err(CalibrationError::Degenerate);
    }
    let slope = (sw * sxy - sx * sy) / det;
    let intercept = (sxx * sy - sx * sxy) / det;
    let chi2: f64 = points
        .iter()
        .map(|p| {
            let r = p.variance_dn2 - (slope * p.mean_dn.abs() + intercept);
            r * r / p.variance_se_dn2.max(floor).powi(2)
        })
        .sum();
    let dof = (points.len() - 2) as f64;
    let red = chi2 / dof;
    let inflate = red.max(1.0);
    Ok(PhotonTransferFit {
        gain_dn_per_electron: slope,
        gain_se: (sw / det * inflate).sqrt(),
        read_variance_dn2: intercept,
        read_variance_se_dn2: (sxx / det * inflate).sqrt(),
        reduced_chi2: red,
        points: points.len(),
    })
}
