//! `farsight-costmap-fusion`: FITAM's fused costmap (polar bins into a
//! Kalman far-field layer, near-field sensing fixing cells, the window
//! following the pose): the stage
//! ([`farsight_costmap_fusion::fusion_stage::FusionStage`]) as a process on
//! the stage runtime.
//!
//! Config: [`farsight_costmap_fusion::stage::FusionStageConfig`].

fn main() {
    farsight_stage::runtime::main::<farsight_costmap_fusion::fusion_stage::FusionStage>();
}
