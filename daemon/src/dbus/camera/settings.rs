//! Capture settings, mode and display map: validated, applied by the frame
//! loop, answered with the first frame that has them.

use tokio::sync::oneshot;
use zbus::object_server::SignalEmitter;

use super::Camera;
use crate::backend::CaptureSettings;
use crate::dbus::errors::{configure_refused, invalid_mode, SdiError};
use crate::frame_loop::Command;
use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
use sdi_core::mode::ModeId;

/// The colour map named `colormap`; `OutOfRange` names the allowed ones.
pub(super) fn parse_colormap(colormap: &str) -> Result<Colormap, SdiError> {
    colormap.parse().map_err(|_| {
        SdiError::OutOfRange(format!(
            "unknown colormap '{}': allowed {}",
            colormap.escape_debug(),
            Colormap::NAMES.join(", ")
        ))
    })
}

/// The display range of `max_abs_dn`: 0 is the symmetric auto range.
pub(super) fn display_range(max_abs_dn: f64) -> DisplayRange {
    if max_abs_dn == 0.0 {
        DisplayRange::SymmetricAuto
    } else {
        DisplayRange::Fixed {
            max_abs_dn: max_abs_dn as f32,
        }
    }
}

impl Camera {
    /// Switches to `mode`; answers with the first frame of it.
    pub(super) async fn switch_mode(
        &self,
        mode: &str,
        emitter: &SignalEmitter<'_>,
    ) -> Result<(u64, u64), SdiError> {
        let m = ModeId::from_name(mode).map_err(|_| invalid_mode(mode))?;
        let guard = self.change_lock.lock().await;
        let (tx, rx) = oneshot::channel();
        self.send(Command::SetMode(m, tx))?;
        let changed = self.state().mode != m;
        self.update(|s| s.mode = m);
        // Other changes may go ahead while this one waits for its frame.
        drop(guard);
        if changed {
            tracing::info!(mode = m.name(), "mode changed");
            let _ = self.mode_changed(emitter).await;
            let _ = self.setup_changed(emitter).await;
        }
        Self::first_frame(rx).await
    }

    pub(super) async fn configure(
        &self,
        emitter: &SignalEmitter<'_>,
        f: impl FnOnce(&mut CaptureSettings),
    ) -> Result<(u64, u64), SdiError> {
        self.require_device()?;
        let guard = self.change_lock.lock().await;
        // A job puts its settings back when it ends: a change now would
        // be undone, so it is refused (the job took the change lock too).
        if let Some(busy) = self.jobs.busy("changing capture settings is refused") {
            return Err(busy);
        }
        let mut capture = self.state().capture;
        f(&mut capture);
        let l = self.info.limits;
        let period_us = 1e6 / capture.frame_rate_hz;
        if capture.exposure_us > period_us {
            return Err(SdiError::OutOfRange(format!(
                "ExposureUs = {} us exceeds the frame period {period_us:.1} us at {} Hz: allowed [{}, {period_us:.1}] us",
                capture.exposure_us, capture.frame_rate_hz, l.exposure_us.0
            )));
        }
        let (first_tx, first_rx) = oneshot::channel();
        let result = self
            .ask(|tx| Command::Configure(capture, tx, first_tx))
            .await?;
        let applied = result.map_err(configure_refused)?;
        self.update(|s| s.capture = applied);
        // Other changes may go ahead while this one waits for its frame.
        drop(guard);
        let _ = self.exposure_us_changed(emitter).await;
        let _ = self.frame_rate_changed(emitter).await;
        let _ = self.modulation_hz_changed(emitter).await;
        Self::first_frame(first_rx).await
    }

    pub(super) async fn set_display(
        &self,
        emitter: &SignalEmitter<'_>,
        f: impl FnOnce(&mut DisplayMap),
    ) -> Result<(u64, u64), SdiError> {
        let guard = self.change_lock.lock().await;
        let mut d = self.state().display;
        f(&mut d);
        let (tx, rx) = oneshot::channel();
        self.send(Command::SetDisplay(d, tx))?;
        self.update(|s| s.display = d);
        drop(guard);
        let _ = self.colormap_changed(emitter).await;
        let _ = self.range_changed(emitter).await;
        Self::first_frame(rx).await
    }
}
