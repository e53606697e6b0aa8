//! The simulator backend: the physically faithful sensor model of sdi-core.

use std::collections::VecDeque;

use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorParams;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

use super::{Backend, BackendError, BackendName, CaptureSettings};

/// Distinct light-travel warnings remembered (each scene and carrier gives
/// one; a sweep of modulation frequencies must not grow memory).
const LIGHT_TRAVEL_REMEMBERED: usize = 16;

pub struct SimBackend {
    sim: Simulator,
    scene: SceneSpec,
    seed: u64,
    /// A scene for every mode (`sdid --scene`), else each mode's own.
    fixed_scene: Option<SceneSpec>,
    /// The light-travel warnings logged lately: a mode switch back and forth
    /// (the depth-edge scene and another) does not log the same one again.
    light_travel_logged: VecDeque<String>,
}

impl SimBackend {
    /// The simulator showing `fixed_scene`, or the scene of `mode` (and of
    /// each mode switched to) when that is `None`.
    pub fn new(
        sensor: SensorParams,
        mode: ModeId,
        seed: u64,
        fixed_scene: Option<SceneSpec>,
    ) -> Result<Self, BackendError> {
        let scene = fixed_scene.clone().unwrap_or_else(|| mode.default_scene());
        let sim = build(sensor, scene.clone(), seed)?;
        let mut b = Self {
            sim,
            scene,
            seed,
            fixed_scene,
            light_travel_logged: VecDeque::new(),
        };
        b.warn_light_travel();
        Ok(b)
    }

    /// Logs the light-travel warning of the current scene and carrier unless
    /// one of the last [`LIGHT_TRAVEL_REMEMBERED`] logged was the same text
    /// (not at every SetMode: the soak test saw 8,000 lines in 2 minutes).
    fn warn_light_travel(&mut self) {
        let Some(text) = sdi_core::simulator::light_travel::light_travel_warning(
            &self.scene,
            self.sim.params().modulation_hz,
        ) else {
            return;
        };
        if !self.light_travel_logged.contains(&text) {
            tracing::warn!("{text}");
            if self.light_travel_logged.len() == LIGHT_TRAVEL_REMEMBERED {
                self.light_travel_logged.pop_front();
            }
            self.light_travel_logged.push_back(text);
        }
    }
}

fn build(sensor: SensorParams, scene: SceneSpec, seed: u64) -> Result<Simulator, BackendError> {
    let mut config = SimConfig::new(sensor, scene);
    config.seed = seed;
    Simulator::new(config).map_err(|e| BackendError::OutOfRange(e.to_string()))
}

impl Backend for SimBackend {
    fn kind(&self) -> BackendName {
        BackendName::Sim
    }

    /// "simulator (MODEL)", and ", scene NAME" with a fixed scene (`sdictl
    /// status` reads it to tell the light-travel warning).
    fn device(&self) -> String {
        match &self.fixed_scene {
            Some(scene) => format!(
                "simulator ({}, scene {})",
                self.sim.params().model,
                scene.name()
            ),
            None => format!("simulator ({})", self.sim.params().model),
        }
    }

    fn sensor(&self) -> &SensorParams {
        self.sim.params()
    }

    fn settings(&self) -> CaptureSettings {
        let p = self.sim.params();
        CaptureSettings {
            exposure_us: p.exposure_us,
            frame_rate_hz: p.frame_rate_hz,
            modulation_hz: p.modulation_hz,
        }
    }

    fn configure(&mut self, s: &CaptureSettings) -> Result<(), BackendError> {
        let mut sensor = self.sim.params().clone();
        sensor.exposure_us = s.exposure_us;
        sensor.frame_rate_hz = s.frame_rate_hz;
        sensor.modulation_hz = s.modulation_hz;
        self.seed = self.seed.wrapping_add(1);
        self.sim = build(sensor, self.scene.clone(), self.seed)?;
        self.warn_light_travel();
        Ok(())
    }

    fn set_mode(&mut self, mode: ModeId) {
        if self.fixed_scene.is_some() {
            return;
        }
        let scene = mode.default_scene();
        if scene != self.scene {
            self.seed = self.seed.wrapping_add(1);
            if let Ok(sim) = build(self.sim.params().clone(), scene.clone(), self.seed) {
                self.sim = sim;
                self.scene = scene;
                self.warn_light_travel();
            }
        }
    }

    fn paced_rate_hz(&self) -> Option<f64> {
        Some(self.sim.params().frame_rate_hz)
    }

    fn capture(
        &mut self,
        illumination: &Illumination,
        frame: &mut Frame,
    ) -> Result<(), BackendError> {
        self.sim.capture(illumination, frame);
        Ok(())
    }
}
