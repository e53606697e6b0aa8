//! `sensor =` / `--sensor`: a preset name (ti, pmd) or the path of a sensor
//! description file (TOML, see `core/sensors/`), parsed once; read with
//! [`SensorSpec::load`].

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use sdi_core::sensor::{SensorDescription, SensorPreset};

/// Which sensor description the simulator (or an offline tool) uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SensorSpec {
    /// A shipped preset.
    Preset(SensorPreset),
    /// A sensor description file.
    File(PathBuf),
}

impl Default for SensorSpec {
    fn default() -> Self {
        Self::Preset(SensorPreset::TiOpt8241)
    }
}

/// A sensor that names nothing, or whose description cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum SensorSpecError {
    #[error("an empty sensor names neither a preset (ti, pmd) nor a file")]
    Empty,
    #[error("'{}' is neither a preset (ti, pmd) nor a readable sensor file: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("'{spec}': {message}")]
    Invalid { spec: String, message: String },
}

impl FromStr for SensorSpec {
    type Err = SensorSpecError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.is_empty() {
            return Err(SensorSpecError::Empty);
        }
        Ok(match s.parse::<SensorPreset>() {
            Ok(p) => Self::Preset(p),
            Err(_) => Self::File(PathBuf::from(s)),
        })
    }
}

impl fmt::Display for SensorSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Preset(p) => f.write_str(p.name()),
            Self::File(path) => write!(f, "{}", path.display()),
        }
    }
}

sdi_core::serde_by_name!(SensorSpec);

impl SensorSpec {
    /// The description named, validated (a file is read here).
    pub fn load(&self) -> Result<SensorDescription, SensorSpecError> {
        let text = match self {
            Self::Preset(p) => std::borrow::Cow::Borrowed(p.toml()),
            Self::File(path) => std::fs::read_to_string(path)
                .map(std::borrow::Cow::Owned)
                .map_err(|source| SensorSpecError::Read {
                    path: path.clone(),
                    source,
                })?,
        };
        SensorDescription::from_toml(&text).map_err(|e| SensorSpecError::Invalid {
            spec: self.to_string(),
            message: e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_and_paths() {
        assert_eq!(
            "ti".parse::<SensorSpec>().unwrap(),
            SensorSpec::Preset(SensorPreset::TiOpt8241)
        );
        assert_eq!(
            "pmd".parse::<SensorSpec>().unwrap(),
            SensorSpec::Preset(SensorPreset::PmdCamBoardNano)
        );
        let f = "/etc/sdi/my.toml".parse::<SensorSpec>().unwrap();
        assert_eq!(f, SensorSpec::File("/etc/sdi/my.toml".into()));
        assert_eq!(f.to_string(), "/etc/sdi/my.toml");
        assert!("".parse::<SensorSpec>().is_err());
        for p in ["ti", "pmd"] {
            let d = p.parse::<SensorSpec>().unwrap().load().unwrap();
            assert!(d.width > 0, "{p}");
        }
        let e = SensorSpec::File("/nonexistent/s.toml".into())
            .load()
            .unwrap_err()
            .to_string();
        assert!(e.contains("neither a preset"), "{e}");
    }

    #[test]
    fn a_description_file_loads() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.toml");
        std::fs::write(&path, SensorPreset::PmdCamBoardNano.toml()).unwrap();
        let spec: SensorSpec = path.to_str().unwrap().parse().unwrap();
        assert_eq!(spec.load().unwrap().width, 165);
        std::fs::write(&path, "width = 0").unwrap();
        assert!(matches!(spec.load(), Err(SensorSpecError::Invalid { .. })));
    }
}
