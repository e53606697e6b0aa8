//! Configuration: `/etc/sdi/sdid.toml` (or `--config`), then command-line overrides.

use std::path::{Path, PathBuf};

use sdi_core::separation::{BilateralParams, LiveMethod};
use serde::{Deserialize, Serialize};

/// Default configuration file.
pub const DEFAULT_PATH: &str = "/etc/sdi/sdid.toml";

/// Everything `sdid` can be configured with. Unknown keys are errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// "auto" (the board when one is attached, else the simulator), "sim",
    /// "replay" or "opt8241".
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
    pub separation: SeparationConfig,
    pub board: BoardSection,
    pub lights: LightsConfig,
    pub recording: RecordingConfig,
}

/// `[recording]`: storage bounds of each recording. The recorder stops
/// cleanly (end record, `RecordingStopped` signal) at either.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecordingConfig {
    /// Largest file, bytes (None: no limit but the free-space floor).
    pub max_bytes: Option<u64>,
    /// Free space to leave on the file system, bytes.
    pub min_free_bytes: u64,
}

impl Default for RecordingConfig {
    fn default() -> Self {
        Self {
            max_bytes: None,
            min_free_bytes: 64 << 20,
        }
    }
}

/// `[board]`: the TI OPT8241-CDK.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BoardSection {
    /// USB serial number, to choose among several boards.
    pub serial: Option<String>,
    /// "no-signal" (default), "simulator" or "exit" (docs/install.md).
    pub on_unplug: String,
    /// Region of interest [x, y, width, height]; columns in steps of 16.
    pub roi: Option<[u32; 4]>,
}

impl Default for BoardSection {
    fn default() -> Self {
        Self {
            serial: None,
            on_unplug: "no-signal".into(),
            roi: None,
        }
    }
}

/// `[lights]`: what drives LS1 and LS2 (docs/hardware.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LightsConfig {
    /// "none", "board", "scpi-tcp", "usbtmc" or "gpio".
    pub driver: String,
    /// scpi-tcp: host:port of the function generator (port 5025).
    pub address: String,
    /// usbtmc: the device node (/dev/usbtmc0).
    pub device: PathBuf,
    /// gpio: the chip and the lines enabling LS1 and LS2.
    pub gpio_chip: PathBuf,
    pub ls1_line: u32,
    pub ls2_line: u32,
}

impl Default for LightsConfig {
    fn default() -> Self {
        Self {
            driver: "none".into(),
            address: String::new(),
            device: PathBuf::from("/dev/usbtmc0"),
            gpio_chip: PathBuf::from("/dev/gpiochip0"),
            ls1_line: 0,
            ls2_line: 1,
        }
    }
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
    /// "auto" (loopback if present, else PipeWire if reachable, else y4m),
    /// "loopback", "pipewire" or "y4m".
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

/// The live separation mode's estimator (section 6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SeparationConfig {
    /// "m3" (bilateral moments of every frame) or "window" (M1 over the last
    /// `window_frames` frames; static scenes).
    pub method: String,
    pub window_frames: usize,
    /// M3's spatial and range sigmas.
    pub sigma_domain_px: f64,
    pub sigma_range_dn: f64,
}

impl Default for SeparationConfig {
    fn default() -> Self {
        let m3 = sdi_core::mode::DEFAULT_BILATERAL;
        Self {
            method: "m3".into(),
            window_frames: 30,
            sigma_domain_px: m3.sigma_domain_px,
            sigma_range_dn: m3.sigma_range_dn,
        }
    }
}

/// Longest sliding window: 2 images of f64 sums per frame held would be huge.
pub const MAX_WINDOW_FRAMES: usize = 1000;

impl SeparationConfig {
    /// The estimator these settings select, or why they are invalid.
    pub fn live_method(&self) -> Result<LiveMethod, String> {
        match self.method.as_str() {
            "m3" => {
                let ok = |v: f64| v.is_finite() && v > 0.0;
                if !ok(self.sigma_domain_px) || !ok(self.sigma_range_dn) {
                    return Err(format!(
                        "separation: sigma_domain_px = {} and sigma_range_dn = {} must be finite and > 0",
                        self.sigma_domain_px, self.sigma_range_dn
                    ));
                }
                Ok(LiveMethod::Bilateral(BilateralParams::new(
                    self.sigma_domain_px,
                    self.sigma_range_dn,
                )))
            }
            "window" if (2..=MAX_WINDOW_FRAMES).contains(&self.window_frames) => {
                Ok(LiveMethod::SlidingWindow {
                    frames: self.window_frames,
                })
            }
            "window" => Err(format!(
                "separation: window_frames = {} must be in 2..={MAX_WINDOW_FRAMES}",
                self.window_frames
            )),
            other => Err(format!(
                "separation: unknown method '{other}': use m3 or window"
            )),
        }
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            backend: "auto".into(),
            sensor: "ti".into(),
            mode: "raw".into(),
            exposure_us: None,
            frame_rate_hz: None,
            modulation_hz: None,
            seed: 1,
            display: DisplayConfig::default(),
            output: OutputConfig::default(),
            replay: ReplayConfig::default(),
            separation: SeparationConfig::default(),
            board: BoardSection::default(),
            lights: LightsConfig::default(),
            recording: RecordingConfig::default(),
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
        let c: Config = toml::from_str("[output]\nsink = \"pipewire\"\n").unwrap();
        assert_eq!(c.output.sink, "pipewire");
        assert_eq!(c.backend, "auto");
        assert_eq!(c.board.on_unplug, "no-signal");
        assert_eq!(c.lights.driver, "none");
        assert!(toml::from_str::<Config>("nope = 1").is_err());
    }

    #[test]
    fn separation_method() {
        let c = Config::default();
        assert!(matches!(
            c.separation.live_method(),
            Ok(LiveMethod::Bilateral(_))
        ));
        let c: Config =
            toml::from_str("[separation]\nmethod = \"window\"\nwindow_frames = 50\n").unwrap();
        assert_eq!(
            c.separation.live_method(),
            Ok(LiveMethod::SlidingWindow { frames: 50 })
        );
        for bad in [
            "method = \"m1\"",
            "method = \"window\"\nwindow_frames = 1",
            "method = \"window\"\nwindow_frames = 100000",
            "sigma_range_dn = -1.0",
            "sigma_domain_px = nan",
        ] {
            let c: Config = toml::from_str(&format!("[separation]\n{bad}\n")).unwrap();
            let e = c.separation.live_method().unwrap_err();
            assert!(e.starts_with("separation:"), "{bad}: {e}");
        }
    }

    #[test]
    fn board_and_lights_sections() {
        let c: Config = toml::from_str(
            "backend = \"opt8241\"\n[board]\nserial = \"EMU0001\"\non_unplug = \"exit\"\nroi = [0, 0, 64, 48]\n[lights]\ndriver = \"scpi-tcp\"\naddress = \"127.0.0.1:5025\"\n",
        )
        .unwrap();
        assert_eq!(c.board.serial.as_deref(), Some("EMU0001"));
        assert_eq!(c.board.on_unplug, "exit");
        assert_eq!(c.board.roi, Some([0, 0, 64, 48]));
        assert_eq!(c.lights.address, "127.0.0.1:5025");
        assert!(toml::from_str::<Config>("[board]\nunplug = 1").is_err());
    }
}
