//! What clients changed (mode, settings, display, recording) and the Stats
//! property read from the frame loop's counters.

use std::path::PathBuf;

use sdi_core::display::DisplayMap;
use sdi_core::mode::ModeId;

use super::Camera;
use crate::backend::CaptureSettings;
use crate::dbus::errors::SdiError;

/// State changed by clients.
#[derive(Debug, Clone)]
pub(super) struct State {
    pub(super) mode: ModeId,
    pub(super) capture: CaptureSettings,
    pub(super) display: DisplayMap,
    pub(super) recording: Option<PathBuf>,
    /// Why the daemon last stopped a recording by itself; reported once by
    /// the next StopRecording, and in Stats.
    pub(super) recording_stopped: Option<String>,
}

impl Camera {
    pub(super) fn state(&self) -> State {
        match self.state.lock() {
            Ok(s) => s.clone(),
            Err(p) => p.into_inner().clone(),
        }
    }

    pub(super) fn update(&self, f: impl FnOnce(&mut State)) {
        match self.state.lock() {
            Ok(mut s) => f(&mut s),
            Err(p) => f(&mut p.into_inner()),
        }
    }

    /// `DeviceUnavailable` while the board is unplugged (nothing stands in).
    pub(super) fn require_device(&self) -> Result<(), SdiError> {
        match self.info.status.as_ref().map(|h| h.get()) {
            Some(st) if !st.available => Err(SdiError::DeviceUnavailable(format!(
                "{}: {}",
                st.device, st.detail
            ))),
            _ => Ok(()),
        }
    }

    /// The file being recorded to, if any.
    pub fn recording_path(&self) -> Option<PathBuf> {
        self.state().recording
    }

    /// The Stats property as of now (the frame rate decays to 0 when frames stop).
    pub fn current_stats(&self) -> sdi_api::Stats {
        let s = self.stats.borrow().clone();
        let now = std::time::Instant::now();
        let (mut device_available, mut device_state, health) =
            match self.info.status.as_ref().map(|h| h.get()) {
                Some(st) => (st.available, st.detail, st.health),
                None => (true, String::new(), None),
            };
        if let Some(why) = s.stalled {
            device_available = false;
            if device_state.is_empty() {
                device_state = format!("no frames: {why}");
            }
        }
        let st = self.state();
        sdi_api::Stats {
            fps: s.fps_at(now, st.capture.frame_rate_hz),
            last_frame_age_s: s.last_frame_at.map_or(-1.0, |t| (now - t).as_secs_f64()),
            device_available,
            device_state,
            recording_stopped: st.recording_stopped.unwrap_or_default(),
            board_temperature_c: health.map_or(f64::NAN, |h| f64::from(h.sensor_c)),
            illumination_temperature_c: health.map_or(f64::NAN, |h| f64::from(h.illumination_c)),
            output_overflows: health.map_or(0, |h| h.output_overflows),
            ..s.counters
        }
    }
}
