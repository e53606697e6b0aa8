//! The client side of `org.sdi.Camera1`: every method and property, with
//! the typed replies of [`crate::types`] and errors as [`SdiError`].

use zbus::proxy;
use zbus::zvariant::Fd;

use std::collections::HashMap;

use crate::types::{CalibrationReply, DarkFrameReply, RecordingReply, Stats};
use crate::SdiError;

#[proxy(
    interface = "org.sdi.Camera1",
    default_service = "org.sdi.Daemon",
    default_path = "/org/sdi/Camera0"
)]
pub trait Camera1 {
    /// Switches the mode; returns (sequence, timestamp_us) of its first
    /// frame, once published (docs/dbus.md, "Setting changes").
    fn set_mode(&self, mode: &str) -> Result<(u64, u64), SdiError>;
    /// Exposure per frame, microseconds; returns the first frame as `set_mode`.
    fn set_exposure_us(&self, exposure_us: f64) -> Result<(u64, u64), SdiError>;
    /// Frame rate, Hz; returns the first frame as `set_mode`.
    fn set_frame_rate(&self, frame_rate_hz: f64) -> Result<(u64, u64), SdiError>;
    /// Carrier frequency, Hz; returns the first frame as `set_mode`.
    fn set_modulation_hz(&self, modulation_hz: f64) -> Result<(u64, u64), SdiError>;
    /// "diverging" or "grey"; returns the first frame as `set_mode`.
    fn set_colormap(&self, colormap: &str) -> Result<(u64, u64), SdiError>;
    /// |DN| at full scale, 0 = auto; returns the first frame as `set_mode`.
    fn set_range(&self, max_abs_dn: f64) -> Result<(u64, u64), SdiError>;
    fn capture_dark_frame(&self, frames: u32) -> Result<DarkFrameReply, SdiError>;
    fn calibrate(&self, frames: u32) -> Result<CalibrationReply, SdiError>;
    fn start_recording(&self, path: &str) -> Result<(), SdiError>;
    fn start_recording_to_fd(&self, fd: Fd<'_>, label: &str) -> Result<(), SdiError>;
    fn stop_recording(&self) -> Result<RecordingReply, SdiError>;
    fn snapshot(&self, path: &str) -> Result<(), SdiError>;
    fn snapshot_to_fd(&self, fd: Fd<'_>, format: &str) -> Result<(), SdiError>;

    /// Current mode name.
    #[zbus(property)]
    fn mode(&self) -> zbus::Result<String>;
    /// All mode names.
    #[zbus(property)]
    fn modes(&self) -> zbus::Result<Vec<String>>;
    #[zbus(property)]
    /// The physical setup the current mode expects: {ls1, ls2, optics}.
    fn setup(&self) -> zbus::Result<HashMap<String, String>>;
    #[zbus(property)]
    fn backend(&self) -> zbus::Result<String>;
    /// "sensor -> output".
    #[zbus(property)]
    fn device(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn format(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn width(&self) -> zbus::Result<u32>;
    #[zbus(property)]
    fn height(&self) -> zbus::Result<u32>;
    #[zbus(property)]
    fn frame_rate(&self) -> zbus::Result<f64>;
    #[zbus(property)]
    fn exposure_us(&self) -> zbus::Result<f64>;
    #[zbus(property)]
    fn modulation_hz(&self) -> zbus::Result<f64>;
    #[zbus(property)]
    fn colormap(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn range(&self) -> zbus::Result<f64>;
    /// Path or label being recorded to, "" when not recording.
    #[zbus(property)]
    fn recording(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn stats(&self) -> zbus::Result<Stats>;
    /// The daemon stopped a recording by itself (size limit, free-space
    /// floor, disk full); `reason` says which.
    #[zbus(signal)]
    fn recording_stopped(&self, path: &str, reason: &str, frames: u64) -> zbus::Result<()>;
}
