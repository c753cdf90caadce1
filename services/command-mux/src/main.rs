//! `farsight-command-mux`: the command mux stage
//! ([`farsight_command_mux::mux_stage::MuxStage`]) as a process on the stage
//! runtime.

fn main() {
    farsight_stage::runtime::main::<farsight_command_mux::mux_stage::MuxStage>();
}
