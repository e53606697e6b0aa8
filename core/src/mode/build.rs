//! Which pipeline runs which mode (the table in [`super::pipeline`]).

use super::pipeline::{Pipeline, PipelineConfig};
use super::separation::SeparationPipeline;
use super::snapshot::SnapshotPipeline;
use super::spec::PipelineKind;
use super::two_shot::TwoShotPipeline;
use super::ModeId;

/// The pipeline of `mode` ([`super::ModeSpec::pipeline`]).
pub fn build_pipeline(mode: ModeId, config: PipelineConfig) -> Box<dyn Pipeline> {
    match mode.spec().pipeline {
        PipelineKind::Snapshot => Box::new(SnapshotPipeline::new(mode, config)),
        PipelineKind::TwoShot => Box::new(TwoShotPipeline::new(config)),
        PipelineKind::Separation => Box::new(SeparationPipeline::new(config)),
    }
}
