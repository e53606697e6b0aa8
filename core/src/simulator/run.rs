//! A mode run on the simulator, as `sdictl sim` and Python's `sdi.simulate`
//! make it (one definition): a dark frame averaged with the sources off
//! (section 4, measurement procedure), then captures through the mode's
//! pipeline, each output with the simulator's ground truth when it changed.

use crate::dark_frame::DarkAccumulator;
use crate::frame::Frame;
use crate::image::{Image, SizeMismatch};
use crate::mode::{build_pipeline, ModeId, ModeOutput, Pipeline, PipelineConfig};
use crate::modulation::Illumination;
use crate::scene::SceneSpec;
use crate::sensor::{mixing_with_adc, SensorDescription};
use crate::separation::{LiveMethod, LiveSeparatorConfig, DEFAULT_BILATERAL};

use super::{SimConfig, Simulator, WellExpectation};

/// Most output frames one run may give.
pub const MAX_FRAMES: usize = 10_000;
/// Most dark frames one run may average.
pub const MAX_DARK_FRAMES: u32 = 10_000;
/// Longest exposure accepted, microseconds.
pub const MAX_EXPOSURE_US: f64 = 1e6;
/// Brightest uniform ambient light accepted, electrons per microsecond per pixel.
pub const MAX_AMBIENT_ELECTRONS_PER_US: f64 = 1e6;

/// The simulator set-up of a run: `sensor` (with `exposure_us` when given)
/// looking at `scene` under uniform `ambient_electrons_per_us` light, plus
/// the sensor's dark current, drawn from `seed`.
pub fn run_config(
    sensor: &SensorDescription,
    scene: SceneSpec,
    exposure_us: Option<f64>,
    ambient_electrons_per_us: f64,
    seed: u64,
) -> SimConfig {
    let mut params = sensor.params();
    if let Some(us) = exposure_us {
        params.exposure_us = us;
    }
    let mut config = SimConfig::new(params, scene);
    // Dark current fills both wells regardless of f: like uncorrelated light
    // of twice the per-well rate, split 50/50 by the square wave.
    config.ambient_electrons_per_us =
        ambient_electrons_per_us + 2.0 * sensor.dark_current_electrons_per_us;
    config.seed = seed;
    config
}

/// Most captures one output may take: two-shot needs a pair, and one more
/// to get in step; anything beyond is a bug.
const MAX_CAPTURES_PER_OUTPUT: usize = 4;

/// Why a run stopped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimRunError {
    #[error(transparent)]
    Dark(#[from] SizeMismatch),
    #[error("mode {mode} produced no output from {captures} captures")]
    NoOutput { mode: ModeId, captures: usize },
}

/// A simulator driven through one mode's pipeline, output by output.
pub struct SimRun {
    sim: Simulator,
    mode: ModeId,
    pipeline: Box<dyn Pipeline>,
    dark_frames: u32,
    dark_dn: Option<Image<f32>>,
    frame: Frame,
    next_sequence: u64,
    /// Start of the first exposure behind the output being formed.
    first_t0_us: Option<f64>,
    outputs: usize,
}

impl SimRun {
    /// Averages `dark_frames` captures with the sources off into the dark
    /// frame the pipeline subtracts, and sets up `mode`'s pipeline (the
    /// separation mode: M3 with the sensor's H).
    pub fn new(mut sim: Simulator, mode: ModeId, dark_frames: u32) -> Result<Self, SimRunError> {
        let (w, h) = (sim.params().width, sim.params().height);
        let mut frame = Frame::new(w, h);
        let mut dark = DarkAccumulator::new(w, h);
        let dark_illumination = Illumination::dark(sim.params().modulation_hz);
        for _ in 0..dark_frames {
            sim.capture(&dark_illumination, &mut frame);
            dark.push(&frame)?;
        }
        let dark_dn = dark.mean_dn();
        let pipeline = build_pipeline(
            mode,
            PipelineConfig {
                dark_frame_dn: dark_dn.clone(),
                separation: LiveSeparatorConfig::new(
                    LiveMethod::Bilateral(DEFAULT_BILATERAL),
                    mixing_with_adc(sim.params()),
                ),
                ..PipelineConfig::default()
            },
        );
        // Numbered on from the dark captures: the two-shot pipeline pairs by it.
        let next_sequence = if dark_frames > 0 {
            frame.sequence + 1
        } else {
            0
        };
        Ok(Self {
            sim,
            mode,
            pipeline,
            dark_frames: dark.frames(),
            dark_dn,
            frame,
            next_sequence,
            first_t0_us: None,
            outputs: 0,
        })
    }

    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }

    pub fn mode(&self) -> ModeId {
        self.mode
    }

    /// Dark frames averaged.
    pub fn dark_frames(&self) -> u32 {
        self.dark_frames
    }

    /// The mean dark frame the pipeline subtracts, DN (None without dark frames).
    pub fn dark_dn(&self) -> Option<&Image<f32>> {
        self.dark_dn.as_ref()
    }

    /// Captures until the pipeline gives an output; `on_capture` sees each
    /// raw capture, `on_output` the output and the ground truth (both with
    /// the caller's `state`): the
    /// expected wells I+ and I- (electrons per exposure under the snapshot
    /// illumination), given for every output of a moving scene and for the
    /// first of a static one.
    pub fn next_output<S, R>(
        &mut self,
        state: &mut S,
        mut on_capture: impl FnMut(&mut S, &Frame),
        on_output: impl FnOnce(&mut S, &ModeOutput, Option<&WellExpectation>) -> R,
    ) -> Result<R, SimRunError> {
        let carrier_hz = self.sim.params().modulation_hz;
        for _ in 0..MAX_CAPTURES_PER_OUTPUT {
            let t0_us = self.sim.time_us();
            self.sim.capture(
                &self.mode.illumination(self.next_sequence, carrier_hz),
                &mut self.frame,
            );
            self.next_sequence = self.frame.sequence + 1;
            let first_t0_us = *self.first_t0_us.get_or_insert(t0_us);
            on_capture(state, &self.frame);
            if let Some(output) = self.pipeline.process(&self.frame) {
                let truth = if !self.sim.scene_is_static() || self.outputs == 0 {
                    if self.mode == ModeId::TwoShot {
                        self.sim
                            .expect_wells(&Illumination::snapshot(carrier_hz), first_t0_us);
                    }
                    Some(self.sim.last_expectation())
                } else {
                    None
                };
                self.outputs += 1;
                self.first_t0_us = None;
                return Ok(on_output(state, output, truth));
            }
        }
        Err(SimRunError::NoOutput {
            mode: self.mode,
            captures: MAX_CAPTURES_PER_OUTPUT,
        })
    }
}
