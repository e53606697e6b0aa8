//! Difference-imaging modes (section 5): what each expects physically and the
//! pipeline of stages it runs on every frame.

mod id;
mod illumination;
mod invalid_pixels;
pub mod pipeline;
mod separation;
mod snapshot;
mod two_shot;

pub use id::{ModeId, PhysicalSetup, UnknownMode};
pub use illumination::{FALLBACK_SCENE, TEMPORAL_TRANSITION_AT};
pub use invalid_pixels::handle_invalid;
pub use pipeline::{
    build_pipeline, flags, ModeOutput, Pipeline, PipelineConfig, SeparatedChannels,
};
pub use separation::{SeparationConfig, SeparationPipeline, DEFAULT_BILATERAL};
pub use snapshot::SnapshotPipeline;
pub use two_shot::TwoShotPipeline;
