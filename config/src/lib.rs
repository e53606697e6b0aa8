//! sdi-config: the `sdid.toml` contract, read by `sdid` and by `sdictl doctor`.
//!
//! Every choice is an enum ([`choice`], [`SensorSpec`]), every value is
//! checked once when the file is loaded ([`Config::validate`]: valid,
//! adjusted or invalid), and `sdid`'s command line parses its overrides into
//! the same types ([`cli`]).
#![forbid(unsafe_code)]

pub mod camera;
pub mod choice;
pub mod cli;
mod file;
pub mod sensor_spec;
mod validate;

use std::path::{Path, PathBuf};

pub use camera::{sim_serial, CameraSection, CameraSections, MAX_CAMERAS};
pub use choice::{BackendKind, LightDriver, OnUnplug, SeparationMethod, SinkKind, UnknownName};
pub use file::{
    BoardSection, Config, DisplaySection, LightsSection, OutputSection, RecordingSection,
    ReplaySection, SeparationSection,
};
pub use sensor_spec::{SensorSpec, SensorSpecError};
pub use validate::{Adjustment, Invalid, MAX_MIN_FREE_BYTES, MIN_RECORDING_BYTES, SCPI_TCP_PORT};

/// Default configuration file.
pub const DEFAULT_PATH: &str = "/etc/sdi/sdid.toml";

/// Why the configuration could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Parse {
        path: PathBuf,
        source: toml::de::Error,
    },
    #[error("{path}: {source}")]
    Invalid { path: PathBuf, source: Invalid },
}

impl Config {
    /// Parses `path` without validating (the command line may still
    /// override settings); without one, the default file if it exists, else
    /// defaults. The path read, if any, is returned too.
    pub fn read(path: Option<&Path>) -> Result<(Self, Option<PathBuf>), ConfigError> {
        let path = match path {
            Some(p) => p.to_owned(),
            None if Path::new(DEFAULT_PATH).exists() => PathBuf::from(DEFAULT_PATH),
            None => return Ok((Self::default(), None)),
        };
        let text = std::fs::read_to_string(&path).map_err(|source| ConfigError::Read {
            path: path.clone(),
            source,
        })?;
        let c = Self::parse(&text).map_err(|source| ConfigError::Parse {
            path: path.clone(),
            source,
        })?;
        Ok((c, Some(path)))
    }

    /// The file's text as sections, not validated yet (what [`Config::read`]
    /// makes of a file).
    pub fn parse(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    /// [`Config::read`] then [`Config::validate`]: the configuration as the
    /// file alone gives it, with the adjustments made.
    pub fn load(path: Option<&Path>) -> Result<(Self, Vec<Adjustment>), ConfigError> {
        let (mut c, read) = Self::read(path)?;
        match c.validate() {
            Ok(adjusted) => Ok((c, adjusted)),
            Err(source) => Err(ConfigError::Invalid {
                path: read.unwrap_or_else(|| PathBuf::from("(defaults)")),
                source,
            }),
        }
    }
}

#[cfg(test)]
mod tests;
