//! The sections of `sdid.toml`. Unknown keys are errors; a missing key takes
//! its default. Values are typed here and checked in [`crate::validate`].
//! A new section is a struct with `#[serde(default, deny_unknown_fields)]`,
//! a field of [`Config`] and its checks in `validate.rs`.

use std::path::PathBuf;

use sdi_core::display::Colormap;
use sdi_core::mode::ModeId;
use sdi_core::scene::SceneId;
use serde::{Deserialize, Serialize};

use crate::camera::CameraSections;
use crate::choice::{BackendKind, LightDriver, OnUnplug, SeparationMethod, SinkKind};
use crate::sensor_spec::SensorSpec;

/// Everything `sdid` can be configured with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Where frames come from.
    pub backend: BackendKind,
    /// The simulator's sensor: a preset or a sensor description file.
    pub sensor: SensorSpec,
    /// Mode at start.
    pub mode: ModeId,
    /// Overrides of the sensor's defaults, each within its
    /// [`sdi_core::sensor::capture_range`].
    pub exposure_us: Option<f64>,
    pub frame_rate_hz: Option<f64>,
    pub modulation_hz: Option<f64>,
    /// Simulator seed (camera N of several uses seed + N).
    pub seed: u64,
    /// How many cameras the simulator shows (serials `sim-0` ...).
    pub cameras: u32,
    /// The simulator's scene for every mode (`None`: each mode's own).
    pub scene: Option<SceneId>,
    pub display: DisplaySection,
    pub output: OutputSection,
    pub replay: ReplaySection,
    pub separation: SeparationSection,
    pub board: BoardSection,
    pub lights: LightsSection,
    pub recording: RecordingSection,
    /// Settings of one camera, by serial.
    pub camera: CameraSections,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            backend: BackendKind::Auto,
            sensor: SensorSpec::default(),
            mode: ModeId::Raw,
            exposure_us: None,
            frame_rate_hz: None,
            modulation_hz: None,
            seed: 1,
            cameras: 1,
            scene: None,
            display: DisplaySection::default(),
            output: OutputSection::default(),
            replay: ReplaySection::default(),
            separation: SeparationSection::default(),
            board: BoardSection::default(),
            lights: LightsSection::default(),
            recording: RecordingSection::default(),
            camera: CameraSections::new(),
        }
    }
}

/// `[display]`: how signed frames are shown.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DisplaySection {
    pub colormap: Colormap,
    /// |DN| at full scale; 0 = symmetric auto.
    pub range_max_abs_dn: f64,
}

impl Default for DisplaySection {
    fn default() -> Self {
        Self {
            colormap: Colormap::Diverging,
            range_max_abs_dn: 0.0,
        }
    }
}

/// `[output]`: where frames are published.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputSection {
    pub sink: SinkKind,
    /// Card label of the view loopback device.
    pub label: String,
    /// Card label of the optional Y16 data device ("" = none).
    pub data_label: String,
    /// y4m fallback: "-" for stdout, or a FIFO path ("" = default).
    pub y4m_path: String,
}

impl Default for OutputSection {
    fn default() -> Self {
        Self {
            sink: SinkKind::Auto,
            label: "SDI camera".into(),
            data_label: String::new(),
            y4m_path: String::new(),
        }
    }
}

/// `[replay]`: the recording `backend = "replay"` plays.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReplaySection {
    pub path: Option<PathBuf>,
    pub looping: bool,
}

/// `[separation]`: the live separation mode's estimator (section 6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SeparationSection {
    pub method: SeparationMethod,
    /// Window of `method = "window"`, frames.
    pub window_frames: usize,
    /// M3's spatial and range sigmas.
    pub sigma_domain_px: f64,
    pub sigma_range_dn: f64,
}

impl Default for SeparationSection {
    fn default() -> Self {
        let m3 = sdi_core::mode::DEFAULT_BILATERAL;
        Self {
            method: SeparationMethod::M3,
            window_frames: 30,
            sigma_domain_px: m3.sigma_domain_px,
            sigma_range_dn: m3.sigma_range_dn,
        }
    }
}

/// `[board]`: the TI OPT8241-CDK.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BoardSection {
    /// USB serial number, to choose among several boards.
    pub serial: Option<String>,
    pub on_unplug: OnUnplug,
    /// Region of interest [x, y, width, height]; columns in steps of 16.
    pub roi: Option<[u32; 4]>,
}

/// `[lights]`: what drives LS1 and LS2 (docs/hardware.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LightsSection {
    pub driver: LightDriver,
    /// scpi-tcp: host:port of the function generator (port 5025 if none).
    pub address: String,
    /// usbtmc: the device node (/dev/usbtmc0).
    pub device: PathBuf,
    /// gpio: the chip and the lines enabling LS1 and LS2.
    pub gpio_chip: PathBuf,
    pub ls1_line: u32,
    pub ls2_line: u32,
}

impl Default for LightsSection {
    fn default() -> Self {
        Self {
            driver: LightDriver::None,
            address: String::new(),
            device: PathBuf::from("/dev/usbtmc0"),
            gpio_chip: PathBuf::from("/dev/gpiochip0"),
            ls1_line: 0,
            ls2_line: 1,
        }
    }
}

/// `[recording]`: storage bounds of each recording. The recorder stops
/// cleanly (end record, `RecordingStopped` signal) at either.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecordingSection {
    /// Largest file, bytes (None: no limit but the free-space floor).
    pub max_bytes: Option<u64>,
    /// Free space to leave on the file system, bytes.
    pub min_free_bytes: u64,
}

impl Default for RecordingSection {
    fn default() -> Self {
        Self {
            max_bytes: None,
            min_free_bytes: 64 << 20,
        }
    }
}
