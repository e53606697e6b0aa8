//! TOML store of calibrations, keyed by sensor model and serial.

use serde::{Deserialize, Serialize};

use super::{CalibrationError, PhotonTransferFit};
use crate::quad_phase::PhaseAxis;
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

/// One board's phase axis (`sdictl calibrate phase`, `crate::quad_phase`):
/// the direction of LS1 - LS2 in the quads' (I, Q) plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhaseRecord {
    pub model: String,
    pub serial: String,
    /// atan2(Q, I) of LS1's light, radians, in [-pi, pi].
    pub angle_rad: f64,
    /// Mean amplitude of the lit source per pixel and frame, DN.
    pub amplitude_dn: f64,
    /// |sum of (I, Q)| / sum of |(I, Q)| over the pixels (1 = one direction).
    pub coherence: f64,
    /// Frames behind the figures.
    pub frames: usize,
}

impl PhaseRecord {
    /// The axis, checked: the file is input like any other.
    pub fn axis(&self) -> Result<PhaseAxis, CalibrationError> {
        PhaseAxis::checked(self.angle_rad).ok_or_else(|| {
            CalibrationError::Store(format!(
                "{} {}: phase angle {} rad is not in [-pi, pi]",
                self.model, self.serial, self.angle_rad
            ))
        })
    }
}

/// All calibrations on a host, as written to a TOML file by the caller.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CalibrationStore {
    #[serde(default, rename = "sensor")]
    pub sensors: Vec<CalibrationRecord>,
    /// Phase axes of raw-quad boards, one per board (`[[phase]]` tables).
    #[serde(default, rename = "phase", skip_serializing_if = "Vec::is_empty")]
    pub phases: Vec<PhaseRecord>,
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

    /// The phase record of a board, if any.
    pub fn phase(&self, model: &str, serial: &str) -> Option<&PhaseRecord> {
        self.phases
            .iter()
            .find(|r| r.model == model && r.serial == serial)
    }

    /// Inserts or replaces the phase record with the same model and serial.
    pub fn upsert_phase(&mut self, record: PhaseRecord) {
        match self
            .phases
            .iter_mut()
            .find(|r| r.model == record.model && r.serial == record.serial)
        {
            Some(r) => *r = record,
            None => self.phases.push(record),
        }
    }

    /// H for a sensor, if calibrated.
    pub fn skellam(&self, model: &str, serial: &str) -> Result<SkellamMixing, CalibrationError> {
        self.get(model, serial)
            .ok_or_else(|| CalibrationError::Store(format!("no calibration for {model} {serial}")))?
            .skellam()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn phase(serial: &str, angle_rad: f64) -> PhaseRecord {
        PhaseRecord {
            model: "TI OPT8241".into(),
            serial: serial.into(),
            angle_rad,
            amplitude_dn: 120.0,
            coherence: 0.99,
            frames: 16,
        }
    }

    #[test]
    fn phase_records_round_trip_beside_the_gain() {
        let mut store = CalibrationStore::default();
        store.upsert_phase(phase("a", 1.0));
        store.upsert_phase(phase("b", -0.5));
        store.upsert_phase(phase("a", 1.25));
        let text = store.to_toml().unwrap();
        assert!(text.contains("[[phase]]"), "{text}");
        let back = CalibrationStore::from_toml(&text).unwrap();
        assert_eq!(back, store);
        assert_eq!(back.phases.len(), 2);
        assert_eq!(back.phase("TI OPT8241", "a").unwrap().angle_rad, 1.25);
        assert!(back.phase("TI OPT8241", "c").is_none());
        // a store written before phase records existed still reads
        let old = CalibrationStore::from_toml("").unwrap();
        assert!(old.phases.is_empty());
    }

    #[test]
    fn a_hostile_phase_record_is_a_typed_error() {
        assert!(phase("a", 1.0).axis().is_ok());
        for bad in [7.0, f64::NAN, f64::NEG_INFINITY] {
            assert!(matches!(
                phase("a", bad).axis(),
                Err(CalibrationError::Store(_))
            ));
        }
        // nan in TOML, a missing field, a string for a number
        let nan = "[[phase]]\nmodel = \"m\"\nserial = \"s\"\nangle_rad = nan\n\
                   amplitude_dn = 1.0\ncoherence = 1.0\nframes = 1\n";
        let store = CalibrationStore::from_toml(nan).unwrap();
        assert!(store.phase("m", "s").unwrap().axis().is_err());
        assert!(CalibrationStore::from_toml("[[phase]]\nmodel = \"m\"\n").is_err());
        assert!(CalibrationStore::from_toml(
            "[[phase]]\nmodel = \"m\"\nserial = \"s\"\nangle_rad = \"x\"\n\
             amplitude_dn = 1.0\ncoherence = 1.0\nframes = 1\n"
        )
        .is_err());
    }
}
