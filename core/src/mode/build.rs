//! Which pipeline runs which mode (the table in [`super::pipeline`]).

use super::pipeline::{Pipeline, PipelineConfig};
use super::separation::SeparationPipeline;
use super::snapshot::SnapshotPipeline;
use super::two_shot::TwoShotPipeline;
use super::ModeId;

/// The pipeline of `mode`.
pub fn build_pipeline(mode: ModeId, config: PipelineConfig) -> Box<dyn Pipeline> {
    match mode {
        ModeId::TwoShot => Box::new(TwoShotPipeline::new(config)),
        ModeId::Separation => Box::new(SeparationPipeline::new(config)),
        ModeId::Raw
        | ModeId::DirectOnly
        | ModeId::BipolarColour
        | ModeId::DepthEdge
        | ModeId::DepthEdgeVertical
        | ModeId::SpatialGradient
        | ModeId::TemporalGradient => Box::new(SnapshotPipeline::new(mode, config)),
    }
}
