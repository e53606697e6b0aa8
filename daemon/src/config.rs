//! Configuration: `/etc/sdi/sdid.toml` (or `--config`), then command-line overrides.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Default configuration file.
pub const DEFAULT_PATH: &str = "/etc/sdi/sdid.toml";

/// Everything `sdid` can be configured with. Unknown keys are errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// "sim" or "replay".
    pub backend: String,
    /// Sensor preset of the simulator: "ti" or "pmd".
    pub sensor: String,
    /// Mode at start.
    pub mode: String,
    /// Overrides of the preset's defaults.
    pub exposure_us: Option<f64>,
    pub frame_rate_hz: Option<f64>,
    pub modulation_hz: Option<f64>,
    /// Simulator seed.
    pub seed: u64,
    pub display: DisplayConfig,
    pub output: OutputConfig,
    pub replay: ReplayConfig,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DisplayConfig {
    /// "diverging" or "grey".
    pub colormap: String,
    /// |DN| at full scale; 0 = symmetric auto.
    pub range_max_abs_dn: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputConfig {
    /// "auto" (loopback if present, else y4m), "loopback" or "y4m".
    pub sink: String,
    /// Card label of the view loopback device.
    pub label: String,
    /// Card label of the optional Y16 data device ("" = none).
    pub data_label: String,
    /// y4m fallback: "-" for stdout, or a FIFO path ("" = default).
    pub y4m_path: String,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReplayConfig {
    pub path: Option<PathBuf>,
    pub looping: bool,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            backend: "sim".into(),
            sensor: "ti".into(),
            mode: "raw".into(),
            exposure_us: None,
            frame_rate_hz: None,
            modulation_hz: None,
            seed: 1,
            display: DisplayConfig::default(),
            output: OutputConfig::default(),
            replay: ReplayConfig::default(),
        }
    }
}

impl Default for DisplayConfig {
    fn default() -> Self {
        Self {
            colormap: "diverging".into(),
            range_max_abs_dn: 0.0,
        }
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            sink: "auto".into(),
            label: "SDI camera".into(),
            data_label: String::new(),
            y4m_path: String::new(),
        }
    }
}

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
}

impl Config {
    /// Loads `path`; without one, the default file if it exists, else defaults.
    pub fn load(path: Option<&Path>) -> Result<Self, ConfigError> {
        let path = match path {
            Some(p) => p.to_owned(),
            None if Path::new(DEFAULT_PATH).exists() => PathBuf::from(DEFAULT_PATH),
            None => return Ok(Self::default()),
        };
        let text = std::fs::read_to_string(&path).map_err(|source| ConfigError::Read {
            path: path.clone(),
            source,
        })?;
        toml::from_str(&text).map_err(|source| ConfigError::Parse { path, source })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects_unknown_keys() {
        let c: Config =
            toml::from_str("mode = \"depth-edge\"\n[output]\nsink = \"y4m\"\n").unwrap();
        assert_eq!(c.mode, "depth-edge");
        assert_eq!(c.output.sink, "y4m");
        assert_eq!(c.backend, "sim");
        assert!(toml::from_str::<Config>("nope = 1").is_err());
    }
}
