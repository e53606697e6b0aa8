//! Lights driven by the modes: a [`Backend`] wrapper that, before each
//! capture, drives LS1 and LS2 as the frame's [`Illumination`] asks
//! (`ModeId::illumination`: two-shot alternates LS1 and LS2 per frame,
//! temporal gradient turns both off), and only when that changes.
//!
//! [`LightSwitch`] is the on/off entry point for whoever knows whether the
//! LEDs should be lit at all (e.g. only while someone watches the output).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::sensor::SensorParams;
use sdi_core::{Frame, Image};

use super::{LightDrive, LightSource};
use crate::backend::{Backend, BackendError, BackendName, CaptureSettings, LightsState, Limits};
use sdi_core::quad_phase::{PhaseAxis, PhaseSums};

/// Shared on/off switch of the light sources (on by default).
#[derive(Debug, Clone)]
pub struct LightSwitch(Arc<AtomicBool>);

impl LightSwitch {
    pub fn new(on: bool) -> Self {
        Self(Arc::new(AtomicBool::new(on)))
    }

    pub fn set(&self, on: bool) {
        self.0.store(on, Ordering::Relaxed);
    }

    pub fn is_on(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

impl Default for LightSwitch {
    fn default() -> Self {
        Self::new(true)
    }
}

/// A backend whose light sources follow the mode.
pub struct LitBackend {
    inner: Box<dyn Backend>,
    lights: Box<dyn LightSource>,
    switch: LightSwitch,
    last: Option<LightDrive>,
    last_error: Option<String>,
}

impl LitBackend {
    pub fn new(inner: Box<dyn Backend>, lights: Box<dyn LightSource>, switch: LightSwitch) -> Self {
        tracing::info!(lights = %lights.describe(), "light sources follow the mode");
        Self {
            inner,
            lights,
            switch,
            last: None,
            last_error: None,
        }
    }

    /// Drives the sources for `ill` if that differs from the last drive.
    /// Failures are logged (once per distinct error) and retried next frame;
    /// they never stop the frames.
    fn drive(&mut self, ill: &Illumination) {
        let drive = LightDrive::from_illumination(ill).gated(Some(self.switch.is_on()));
        if self.last == Some(drive) {
            return;
        }
        match self.lights.apply(&drive) {
            Ok(()) => {
                self.last = Some(drive);
                self.last_error = None;
            }
            Err(e) => {
                let text = e.to_string();
                if self.last_error.as_deref() != Some(text.as_str()) {
                    tracing::warn!("light sources: {text}");
                    self.last_error = Some(text);
                }
            }
        }
    }
}

impl Backend for LitBackend {
    fn kind(&self) -> BackendName {
        self.inner.kind()
    }

    fn device(&self) -> String {
        self.inner.device()
    }

    fn serial(&self) -> Option<String> {
        self.inner.serial()
    }

    fn sensor(&self) -> &SensorParams {
        self.inner.sensor()
    }

    fn limits(&self) -> Limits {
        self.inner.limits()
    }

    fn settings(&self) -> CaptureSettings {
        self.inner.settings()
    }

    fn configure(&mut self, settings: &CaptureSettings) -> Result<(), BackendError> {
        self.inner.configure(settings)?;
        // The carrier may have changed: program the sources again.
        self.last = None;
        Ok(())
    }

    fn set_mode(&mut self, mode: ModeId) {
        self.inner.set_mode(mode)
    }

    fn capture(
        &mut self,
        illumination: &Illumination,
        frame: &mut Frame,
    ) -> Result<(), BackendError> {
        self.drive(illumination);
        self.inner.capture(illumination, frame)
    }

    fn replays(&self) -> bool {
        self.inner.replays()
    }

    fn paced_rate_hz(&self) -> Option<f64> {
        self.inner.paced_rate_hz()
    }

    fn take_dark_frame(&mut self) -> Option<(u32, Image<f32>)> {
        self.inner.take_dark_frame()
    }

    fn measure_phase(&mut self, on: bool) -> Result<(), BackendError> {
        self.inner.measure_phase(on)
    }

    fn take_phase_sums(&mut self) -> Option<PhaseSums> {
        self.inner.take_phase_sums()
    }

    fn set_phase_axis(&mut self, axis: Option<PhaseAxis>) -> Result<(), BackendError> {
        self.inner.set_phase_axis(axis)
    }

    fn lights(&self) -> Option<LightsState> {
        Some(LightsState {
            rig: self.lights.describe(),
            refused: self.last_error.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::sim::SimBackend;
    use crate::light::LightError;
    use sdi_core::modulation::SourceDrive;
    use sdi_core::sensor::SensorPreset;
    use std::sync::Mutex;

    struct Recorder(Arc<Mutex<Vec<LightDrive>>>);

    impl LightSource for Recorder {
        fn describe(&self) -> String {
            "recorder".into()
        }
        fn apply(&mut self, d: &LightDrive) -> Result<(), LightError> {
            self.0.lock().unwrap().push(*d);
            Ok(())
        }
    }

    #[test]
    fn sources_follow_the_mode_and_the_switch() {
        let mut p = SensorPreset::TiOpt8241.params();
        p.width = 16;
        p.height = 8;
        p.frame_rate_hz = 240.0;
        let sim = SimBackend::new(p, ModeId::TwoShot, 1, None).unwrap();
        let seen = Arc::new(Mutex::new(Vec::new()));
        let switch = LightSwitch::default();
        let mut b = LitBackend::new(
            Box::new(sim),
            Box::new(Recorder(seen.clone())),
            switch.clone(),
        );
        let mut f = Frame::new(16, 8);
        for i in 0..4 {
            b.capture(&ModeId::TwoShot.illumination(i, 12e6), &mut f)
                .unwrap();
        }
        let pairs: Vec<_> = seen
            .lock()
            .unwrap()
            .iter()
            .map(|d| (d.ls1, d.ls2))
            .collect();
        use SourceDrive::{Modulated as M, Off as O};
        assert_eq!(pairs, vec![(M, O), (O, M), (M, O), (O, M)]);
        // Unchanged drive: nothing sent; switched off: both dark.
        let ill = ModeId::Raw.illumination(0, 12e6);
        b.capture(&ill, &mut f).unwrap();
        b.capture(&ill, &mut f).unwrap();
        assert_eq!(seen.lock().unwrap().len(), 5);
        switch.set(false);
        b.capture(&ill, &mut f).unwrap();
        let last = *seen.lock().unwrap().last().unwrap();
        assert_eq!((last.ls1, last.ls2), (O, O));
    }
}
