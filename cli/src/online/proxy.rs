//! Client side of `org.sdi.Camera1`.

use std::collections::HashMap;

use zbus::proxy;
use zbus::zvariant::{Fd, OwnedValue};

#[proxy(
    interface = "org.sdi.Camera1",
    default_service = "org.sdi.Daemon",
    default_path = "/org/sdi/Camera0"
)]
pub trait Camera1 {
    /// Returns (sequence, timestamp_us) of the first frame under the new setting.
    fn set_mode(&self, mode: &str) -> zbus::Result<(u64, u64)>;
    /// Returns (sequence, timestamp_us) of the first frame under the new setting.
    fn set_exposure_us(&self, exposure_us: f64) -> zbus::Result<(u64, u64)>;
    /// Returns (sequence, timestamp_us) of the first frame under the new setting.
    fn set_frame_rate(&self, frame_rate_hz: f64) -> zbus::Result<(u64, u64)>;
    /// Returns (sequence, timestamp_us) of the first frame under the new setting.
    fn set_modulation_hz(&self, modulation_hz: f64) -> zbus::Result<(u64, u64)>;
    /// Returns (sequence, timestamp_us) of the first frame under the new setting.
    fn set_colormap(&self, colormap: &str) -> zbus::Result<(u64, u64)>;
    /// Returns (sequence, timestamp_us) of the first frame under the new setting.
    fn set_range(&self, max_abs_dn: f64) -> zbus::Result<(u64, u64)>;
    fn capture_dark_frame(&self, frames: u32) -> zbus::Result<HashMap<String, OwnedValue>>;
    fn calibrate(&self, frames: u32) -> zbus::Result<HashMap<String, OwnedValue>>;
    fn start_recording(&self, path: &str) -> zbus::Result<()>;
    fn stop_recording(&self) -> zbus::Result<HashMap<String, OwnedValue>>;
    fn snapshot(&self, path: &str) -> zbus::Result<()>;
    fn start_recording_to_fd(&self, fd: Fd<'_>, label: &str) -> zbus::Result<()>;
    fn snapshot_to_fd(&self, fd: Fd<'_>, format: &str) -> zbus::Result<()>;

    #[zbus(property)]
    fn mode(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn stats(&self) -> zbus::Result<HashMap<String, OwnedValue>>;
    #[zbus(property)]
    fn frame_rate(&self) -> zbus::Result<f64>;
}
