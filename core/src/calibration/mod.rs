//! Sensor calibration: dark frame and fixed pattern from frames with the
//! sources off, photon-transfer fit of rho*eta and sigma_read^2 (EMVA 1288
//! spirit; the paper's Fig. exp_variance), and a TOML store keyed by sensor
//! model and serial that yields the [`crate::sensor::SkellamMixing`] H.

mod dark;
mod error;
pub mod noise_analysis;
mod photon_transfer;
mod store;

pub use dark::DarkCalibration;
pub use error::CalibrationError;
pub use noise_analysis::{linear_fit, ratio_with_se, LinearFit};
pub use photon_transfer::{fit_photon_transfer, PhotonTransferFit, PtcPoint};
pub use store::{CalibrationRecord, CalibrationStore, PhaseRecord};
