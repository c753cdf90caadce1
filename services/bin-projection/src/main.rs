//! `farsight-bin-projection`: per-camera perception -> bins around the robot
//! (LRN angular bins on `bins/angular`, or FITAM polar bins on `bins/polar`):
//! the stage ([`farsight_bin_projection::projection_stage::ProjectionStage`])
//! as a process on the stage runtime.
//!
//! Config: [`farsight_bin_projection::stage::BinProjectionConfig`].

fn main() {
    farsight_stage::runtime::main::<farsight_bin_projection::projection_stage::ProjectionStage>();
}
