//! TOML store of calibrations, keyed by sensor model and serial.

use serde::{Deserialize, Serialize};

use super::{CalibrationError, PhotonTransferFit};
use crate::sensor::SkellamMixing;

/// One sensor's calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    pub model: String,
    pub serial: String,
    /// g = rho eta, DN per electron, with its standard error.
    pub gain_dn_per_electron: f64,
    pub gain_se: f64,
    /// (rho sigma_read)^2, DN^2, with its standard error.
    pub read_variance_dn2: f64,
    pub read_variance_se_dn2: f64,
    /// Fixed-pattern noise of the dark map, DN.
    pub fixed_pattern_sigma_dn: f64,
    /// Frames or points behind the figures.
    pub dark_frames: usize,
    pub ptc_points: usize,
}

impl CalibrationRecord {
    pub fn from_fit(
        model: &str,
        serial: &str,
        fit: &PhotonTransferFit,
        fixed_pattern_sigma_dn: f64,
        dark_frames: usize,
    ) -> Self {
        Self {
            model: model.into(),
            serial: serial.into(),
            gain_dn_per_electron: fit.gain_dn_per_electron,
            gain_se: fit.gain_se,
            read_variance_dn2: fit.read_variance_dn2.max(0.0),
            read_variance_se_dn2: fit.read_variance_se_dn2,
            fixed_pattern_sigma_dn,
            dark_frames,
            ptc_points: fit.points,
        }
    }

    /// H of this calibration.
    pub fn skellam(&self) -> Result<SkellamMixing, CalibrationError> {
        let g = self.gain_dn_per_electron;
        let r = self.read_variance_dn2;
        if !(g.is_finite() && g > 0.0 && r.is_finite() && r >= 0.0) {
            return Err(CalibrationError::Store(format!(
                "{} {}: gain {g} / read variance {r} out of range",
                self.model, self.serial
            )));
        }
        Ok(SkellamMixing::new(g, r))
    }
}

/// All calibrations on a host, as written to a TOML file by the caller.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CalibrationStore {
    #[serde(default, rename = "sensor")]
    pub sensors: Vec<CalibrationRecord>,
}

impl CalibrationStore {
    pub fn from_toml(text: &str) -> Result<Self, CalibrationError> {
        toml::from_str(text).map_err(|e| CalibrationError::Store(e.to_string()))
    }

    pub fn to_toml(&self) -> Result<String, CalibrationError> {
        toml::to_string_pretty(self).map_err(|e| CalibrationError::Store(e.to_string()))
    }

    pub fn get(&self, model: &str, serial: &str) -> Option<&CalibrationRecord> {
        self.sensors
            .iter()
            .find(|r| r.model == model && r.serial == serial)
    }

    /// Inserts or replaces the record with the same model and serial.
    pub fn upsert(&mut self, record: CalibrationRecord) {
        match self
            .sensors
            .iter_mut()
            .find(|r| r.model == record.model && r.serial == record.serial)
        {
            Some(r) => *r = record,
            None => self.sensors.push(record),
        }
    }

    /// H for a sensor, if calibrated.
    pub fn skellam(&self, model: &str, serial: &str) -> Result<SkellamMixing, CalibrationError> {
        self.get(model, serial)
            .ok_or_else(|| CalibrationError::Store(format!("no calibration for {model} {serial}")))?
            .skellam()
    }
}
