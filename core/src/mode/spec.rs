//! What a mode is, as one value per mode ([`ModeId::spec`]): the setup the
//! operator builds, how the sources are driven, the simulator scene that
//! shows it off and the pipeline that turns its frames into output.

use serde::Serialize;

use super::illumination::IlluminationKind;
use super::ModeId;
use crate::scene::{SceneId, SceneSpec};

/// One mode's entry in the table of modes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModeSpec {
    /// What the operator must set up; the daemon cannot move optics.
    pub setup: PhysicalSetup,
    /// How LS1, LS2 and f(t) are driven frame by frame.
    pub illumination: IlluminationKind,
    /// The simulator scene that shows the mode off.
    pub default_scene: SceneId,
    /// Which pipeline turns its frames into output.
    pub pipeline: PipelineKind,
}

/// What the operator must set up for a mode: the daemon cannot move optics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct PhysicalSetup {
    pub ls1: &'static str,
    pub ls2: &'static str,
    pub optics: &'static str,
}

/// The pipelines a mode can run ([`super::build_pipeline`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PipelineKind {
    /// One frame in, its in-pixel difference out (eq. pixeleff).
    Snapshot,
    /// Frame pairs A (LS1) and B (LS2), subtracted after the ADC (section 5.5).
    TwoShot,
    /// The snapshot difference plus I+ and I- recovered live (section 6).
    Separation,
}

impl ModeId {
    /// What the operator must build for this mode (`sdictl status` shows it).
    pub fn setup(self) -> PhysicalSetup {
        self.spec().setup
    }

    /// The simulator scene that shows this mode off, with its defaults.
    pub fn default_scene(self) -> SceneSpec {
        self.spec().default_scene.spec()
    }
}
