//! The daemon's view of sdi-core's modes and display mapping, in one place.

pub use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
pub use sdi_core::mode::{build_pipeline, ModeId, ModeOutput, Pipeline, PipelineConfig};
use sdi_core::modulation::Illumination;
use sdi_core::scene::SceneSpec;

/// How the sources are driven for `mode` in frame `frame_index`.
pub fn illumination(mode: ModeId, frame_index: u64, carrier_hz: f64) -> Illumination {
    mode.illumination(frame_index, carrier_hz)
}

/// The simulator scene that shows `mode` off.
pub fn default_scene(mode: ModeId) -> SceneSpec {
    mode.default_scene()
}
