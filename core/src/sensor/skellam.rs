//! The Skellam mixing matrix H (eq. skellammatrix), expressed in DN.
//!
//! With g = rho * eta (DN per electron):
//! (mu, sigma^2 - sigma_read^2) = H (I+, I-),  H = [[g, -g], [g^2, g^2]],
//! det H = 2 g^3 = 2 rho^3 eta^3.

use serde::{Deserialize, Serialize};

/// H for one sensor configuration, plus the read-noise variance it subtracts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SkellamMixing {
    /// g = rho * eta, DN per electron.
    pub gain_dn_per_electron: f64,
    /// (rho * sigma_read)^2, DN^2.
    pub read_variance_dn2: f64,
}

impl SkellamMixing {
    pub fn new(gain_dn_per_electron: f64, read_variance_dn2: f64) -> Self {
        Self {
            gain_dn_per_electron,
            read_variance_dn2,
        }
    }

    /// The 2x2 matrix H, row-major.
    pub fn matrix(&self) -> [[f64; 2]; 2] {
        let g = self.gain_dn_per_electron;
        [[g, -g], [g * g, g * g]]
    }

    /// det H = 2 g^3.
    pub fn determinant(&self) -> f64 {
        2.0 * self.gain_dn_per_electron.powi(3)
    }

    /// Expected mean (DN) and variance (DN^2) of a pixel whose wells expect
    /// `i_plus_electrons` and `i_minus_electrons` (eq. skellamvar).
    pub fn forward(&self, i_plus_electrons: f64, i_minus_electrons: f64) -> (f64, f64) {
        let g = self.gain_dn_per_electron;
        (
            g * (i_plus_electrons - i_minus_electrons),
            g * g * (i_plus_electrons + i_minus_electrons) + self.read_variance_dn2,
        )
    }

    /// (I+, I-) = H^-1 (mu, sigma^2 - sigma_read^2), electrons (section 6).
    /// Written as half-sum and half-difference, which stays exact when det H is tiny.
    pub fn inverse(&self, mean_dn: f64, variance_dn2: f64) -> (f64, f64) {
        let g = self.gain_dn_per_electron;
        let sum = (variance_dn2 - self.read_variance_dn2) / (g * g);
        let diff = mean_dn / g;
        (0.5 * (sum + diff), 0.5 * (sum - diff))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_undoes_forward() {
        let h = SkellamMixing::new(0.05, 15.0);
        let (m, v) = h.forward(1234.0, 567.0);
        let (p, n) = h.inverse(m, v);
        assert!((p - 1234.0).abs() < 1e-6 && (n - 567.0).abs() < 1e-6);
    }

    #[test]
    fn determinant_is_two_g_cubed() {
        let h = SkellamMixing::new(0.3, 0.0);
        let [[a, b], [c, d]] = h.matrix();
        assert!(((a * d - b * c) - h.determinant()).abs() < 1e-12);
    }
}
