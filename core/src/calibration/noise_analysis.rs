//! Section 5.5 (Fig. exp_variance): per-pixel temporal variance against
//! intensity, fitted by a straight line for the snapshot and the two-shot
//! difference. Snapshot reads out once, var = g^2 (I+ + I-) + sigma_read^2
//! (eq. skellamvar); two-shot reads out twice, var = g^2 (I+ + I-) +
//! 2 sigma_read^2 (eq. pre_post_noise): the low-light intercepts differ by 2
//! (paper: 1.97 PMD, 1.99 +- 0.37 TI).

use super::CalibrationError;

/// Ordinary least squares y = intercept + slope x with standard errors from
/// the residuals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearFit {
    pub intercept: f64,
    pub slope: f64,
    pub intercept_se: f64,
    pub slope_se: f64,
    pub points: usize,
}

/// Fits a line through at least three finite points with distinct x.
pub fn linear_fit(xs: &[f64], ys: &[f64]) -> Result<LinearFit, CalibrationError> {
    let pts: Vec<(f64, f64)> = xs
        .iter()
        .zip(ys)
        .map(|(&x, &y)| (x, y))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let n = pts.len();
    if n < 3 {
        return Err(CalibrationError::Store(format!(
            "a line with uncertainties needs 3 finite points, got {n}"
        )));
    }
    let nf = n as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / nf;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / nf;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx <= 0.0 {
        return Err(CalibrationError::Store("all intensities are equal".into()));
    }
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let rss: f64 = pts
        .iter()
        .map(|p| (p.1 - intercept - slope * p.0).powi(2))
        .sum();
    let s2 = rss / (nf - 2.0);
    Ok(LinearFit {
        intercept,
        slope,
        intercept_se: (s2 * (1.0 / nf + mx * mx / sxx)).sqrt(),
        slope_se: (s2 / sxx).sqrt(),
        points: n,
    })
}

/// a / b with its first-order standard error (independent a and b).
pub fn ratio_with_se(a: f64, a_se: f64, b: f64, b_se: f64) -> (f64, f64) {
    let r = a / b;
    (
        r,
        r.abs() * ((a_se / a).powi(2) + (b_se / b).powi(2)).sqrt(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_line_has_zero_uncertainty_and_noisy_one_does_not() {
        let xs = [0.0, 1.0, 2.0, 3.0];
        let f = linear_fit(&xs, &[1.0, 3.0, 5.0, 7.0]).unwrap();
        assert!((f.intercept - 1.0).abs() < 1e-12 && (f.slope - 2.0).abs() < 1e-12);
        assert!(f.intercept_se < 1e-9);
        let f = linear_fit(&xs, &[1.1, 2.9, 5.2, 6.8]).unwrap();
        assert!(f.intercept_se > 0.0 && f.slope_se > 0.0);
        assert!(linear_fit(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]).is_err());
        assert!(linear_fit(&[1.0, f64::NAN], &[1.0, 2.0]).is_err());
        let (r, se) = ratio_with_se(2.0, 0.2, 1.0, 0.1);
        assert!((r - 2.0).abs() < 1e-12 && (se - 2.0 * 0.02f64.sqrt()).abs() < 1e-12);
    }
}
