//! `farsight-camera-ingest`: the camera-ingest stage
//! ([`farsight_camera_ingest::ingest_stage::IngestStage`]) as a process on
//! the stage runtime.

fn main() {
    farsight_stage::runtime::main::<farsight_camera_ingest::ingest_stage::IngestStage>();
}
