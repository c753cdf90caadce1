//! `farsight-subgoal-selection`: the subgoal stage
//! ([`farsight_subgoal_selection::subgoal_stage::SubgoalStage`]: POVNav, LRN,
//! the goal heuristic, D* Lite or HIP) as a process on the stage runtime.

fn main() {
    farsight_stage::runtime::main::<farsight_subgoal_selection::subgoal_stage::SubgoalStage>();
}
