//! `farsight-inference`: the inference stage
//! ([`farsight_inference::inference_stage::InferenceStage`]) as a process on
//! the stage runtime.

fn main() {
    farsight_stage::runtime::main::<farsight_inference::inference_stage::InferenceStage>();
}
