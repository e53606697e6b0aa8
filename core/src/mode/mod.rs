//! Difference-imaging modes (section 5): what each expects physically and the
//! pipeline of stages it runs on every frame.

mod build;
mod id;
mod illumination;
mod invalid_pixels;
mod output;
pub mod pipeline;
mod separation;
mod snapshot;
mod spec;
mod two_shot;

/// Re-exported for the daemon's configuration defaults.
pub use crate::separation::DEFAULT_BILATERAL;
pub use build::build_pipeline;
pub use id::{ModeId, UnknownMode};
pub use illumination::{IlluminationKind, TEMPORAL_TRANSITION_AT};
pub use invalid_pixels::handle_invalid;
pub use output::{ModeOutput, SeparatedChannels};
pub use pipeline::{Pipeline, PipelineConfig};
pub use separation::SeparationPipeline;
pub use snapshot::SnapshotPipeline;
pub use spec::{ModeSpec, PhysicalSetup, PipelineKind};
pub use two_shot::TwoShotPipeline;
