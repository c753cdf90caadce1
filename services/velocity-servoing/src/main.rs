//! `farsight-velocity-servoing`: the servo stage
//! ([`farsight_velocity_servoing::servo_stage::ServoStage`]) as a process on
//! the stage runtime.

fn main() {
    farsight_stage::runtime::main::<farsight_velocity_servoing::servo_stage::ServoStage>();
}
