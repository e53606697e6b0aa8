//! Fixed facts about the camera: its backend, devices, limits and storage.

use std::path::PathBuf;

use crate::backend::Limits;
use crate::sink::SinkInfo;
use sdi_config::RecordingSection;

/// Fixed facts about this camera, known at start.
#[derive(Debug, Clone)]
pub struct CameraInfo {
    /// The camera's name among several: the board's USB serial, `sim-N`.
    pub serial: String,
    pub backend: crate::backend::BackendName,
    pub device: String,
    /// The simulator's scene fixed by `[sim] scene`; None: each mode's own.
    pub scene: Option<sdi_core::scene::SceneId>,
    pub sink: SinkInfo,
    pub limits: Limits,
    pub sensor: sdi_core::sensor::SensorParams,
    /// Where calibrations are stored ([`crate::calibration_store`]); None = not stored.
    pub state_dir: Option<PathBuf>,
    /// Live backend state (the board: unplugged, simulator standing in).
    pub status: Option<crate::backend::status::StatusHandle>,
    /// Storage bounds of recordings.
    pub recording: RecordingSection,
    /// The rig `[lights]` drives; None when sdid drives no lights.
    pub lights: Option<String>,
}
