//! Several cameras in one sdid: the simulator's count (`cameras = N`,
//! serials `sim-0`, `sim-1`, ...) and each camera's own settings,
//! `[camera."SERIAL"]`, laid over the file's for that camera alone.

use std::collections::BTreeMap;

use sdi_core::display::Colormap;
use sdi_core::mode::ModeId;
use sdi_core::scene::SceneId;
use serde::{Deserialize, Serialize};

use crate::file::Config;
use crate::validate::Invalid;

/// Most cameras one sdid serves (each has its own frame-loop thread).
pub const MAX_CAMERAS: u32 = 8;

/// `[camera."SERIAL"]`: what differs for the camera of that serial (the
/// board's USB serial, `sim-N` for the simulator). A key left out takes
/// the file's value.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraSection {
    pub mode: Option<ModeId>,
    pub exposure_us: Option<f64>,
    pub frame_rate_hz: Option<f64>,
    pub modulation_hz: Option<f64>,
    pub scene: Option<SceneId>,
    pub colormap: Option<Colormap>,
    pub range_max_abs_dn: Option<f64>,
}

/// Each serial's section.
pub type CameraSections = BTreeMap<String, CameraSection>;

/// The serial of the simulator's camera `index`.
pub fn sim_serial(index: u32) -> String {
    format!("sim-{index}")
}

impl Config {
    /// The configuration of the camera `serial`: its section over the
    /// file's settings. The result has no sections of its own.
    pub fn for_camera(&self, serial: &str) -> Config {
        let mut c = self.clone();
        c.camera = CameraSections::new();
        let Some(s) = self.camera.get(serial) else {
            return c;
        };
        c.mode = s.mode.unwrap_or(c.mode);
        c.exposure_us = s.exposure_us.or(c.exposure_us);
        c.frame_rate_hz = s.frame_rate_hz.or(c.frame_rate_hz);
        c.modulation_hz = s.modulation_hz.or(c.modulation_hz);
        c.scene = s.scene.or(c.scene);
        c.display.colormap = s.colormap.unwrap_or(c.display.colormap);
        c.display.range_max_abs_dn = s.range_max_abs_dn.unwrap_or(c.display.range_max_abs_dn);
        c
    }

    /// The simulated cameras' serials, in order.
    pub fn sim_serials(&self) -> Vec<String> {
        (0..self.cameras).map(sim_serial).collect()
    }
}

/// A `[camera."SERIAL"]` setting that cannot be used: the section's name
/// before the key's own message.
pub(crate) fn in_section(serial: &str, e: Invalid) -> Invalid {
    Invalid {
        key: "camera",
        reason: format!("[camera.{serial:?}] {}: {}", e.key, e.reason),
    }
}
