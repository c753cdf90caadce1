//! `farsight bench nav`: the navigation benchmark. N seeded trials per
//! scenario for each simulator graph, side by side in one run. A trial runs
//! the graph file as it ships: its nodes built as the stages' library types
//! with the graph's own configs, composed by the in-process executor against
//! the simulator (`crate::lockstep`), so a trial drives the track that
//! `farsight demo` drives with the same graph as processes
//! (`tests/closed_loop.rs` checks that, per method). The benchmark has no
//! tuning of its own: what it measures is what ships.
//!
//! Rows (each graph's header comment says more):
//! - `lrn_learned` (`graphs/sim/lrn.toml`): the shipped LRN affordance model
//!   -> angular bins -> LRN's goal-conditioned head -> the servo's heading law;
//! - `goal_heuristic` (`graphs/sim/lrn-goal-heuristic.toml`): LRN's
//!   baseline, the observed bin nearest the goal;
//! - `dstar_no_far_field` (`graphs/sim/dstar-lite.toml`): near field ->
//!   fused map -> D* Lite -> carrot (FITAM's baseline);
//! - `fitam_gt` (`graphs/sim/fitam-gt.toml`): the same plus the far field
//!   labelled from the true world (FITAM's "GT labels" row);
//! - `fitam_learned` (`graphs/sim/fitam.toml`): the far field from the
//!   shipped FITAM model through inference and bin projection;
//! - `povnav_oracle` (`graphs/sim/povnav-oracle.toml`): POVNav on the class
//!   image -> the POVNav servo law;
//! - `povnav_lrn` (`graphs/sim/povnav-lrn.toml`): LRN's heading (the
//!   shipped model) as POVNav's goal, POVNav on HSV navigability, two
//!   inference instances on one camera;
//! - `lrn_local_planner` (`graphs/sim/lrn-dstar.toml`): LRN's heading as
//!   the goal of a D* Lite local planner on the fused near field (the
//!   composition LRN's paper runs).
//!
//! `--list` prints the rows and their graph files (the process tests take
//! the list from there). `--graphs` runs other graph files instead (a row per file, named by its
//! stem): the simulator provides what a graph's `[[external]]` topics ask
//! for (its cameras, `--oracle` navigability, `--far-field-oracle` bins).
//!
//! Metrics per trial come from `farsight_sim::episode`; the table gives the
//! success rate with a 95% Wilson interval and means with 95% normal
//! intervals (path length, time and traversal cost over the successful
//! trials; interventions over all).

use crate::bench::NavArgs;
use crate::graph::Graph;
use crate::lockstep::{self, Trial};
use anyhow::Result;
use farsight_sim::episode::{Outcome, Summary};
use farsight_sim::sim_robot::SimOptions;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The benchmark's rows: name and graph file (relative to the repository).
pub const METHODS: [(&str, &str); 8] = [
    ("lrn_learned", "graphs/sim/lrn.toml"),
    ("goal_heuristic", "graphs/sim/lrn-goal-heuristic.toml"),
    ("dstar_no_far_field", "graphs/sim/dstar-lite.toml"),
    ("fitam_gt", "graphs/sim/fitam-gt.toml"),
    ("fitam_learned", "graphs/sim/fitam.toml"),
    ("povnav_oracle", "graphs/sim/povnav-oracle.toml"),
    ("povnav_lrn", "graphs/sim/povnav-lrn.toml"),
    ("lrn_local_planner", "graphs/sim/lrn-dstar.toml"),
];

/// The simulator a graph asks for: a camera for each `camera/<name>/...`
/// or `perception/<name>/navigability` topic written outside the graph, the
/// oracle's navigability and far field when the graph reads them from
/// outside; the simulator's defaults otherwise (640x360 at 10 Hz).
pub fn sim_options(graph: &Graph, scenario: &str, seed: u64, max_time_s: f64) -> SimOptions {
    let external: Vec<&str> = graph
        .topics
        .iter()
        .filter(|(_, e)| e.writers.iter().any(|w| w.starts_with("external")))
        .map(|(t, _)| t.as_str())
        .collect();
    let mut cameras: Vec<String> = Vec::new();
    for t in &external {
        let parts: Vec<&str> = t.split('/').collect();
        if let ["camera" | "perception", name, _] = parts.as_slice() {
            if !cameras.iter().any(|c| c == name) {
                cameras.push(name.to_string());
            }
        }
    }
    let defaults = SimOptions::default();
    SimOptions {
        scenario: scenario.to_string(),
        seed,
        max_time_s,
        cameras: if cameras.is_empty() {
            defaults.cameras.clone()
        } else {
            cameras
        },
        oracle: external
            .iter()
            .any(|t| t.starts_with("perception/") && t.ends_with("/navigability")),
        far_field_oracle: external.contains(&"bins/polar"),
        ..defaults
    }
}

/// One trial: a graph on a scenario and seed, to the goal or the time limit.
pub fn trial(
    graph: &Graph,
    scenario: &str,
    seed: u64,
    max_time_s: f64,
    trace: Option<&Path>,
) -> Result<Trial> {
    lockstep::drive(
        graph,
        &sim_options(graph, scenario, seed, max_time_s),
        trace,
    )
}

fn wilson(successes: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 0.0);
    }
    let (z, n_f) = (1.96f64, n as f64);
    let p = successes as f64 / n_f;
    let denom = 1.0 + z * z / n_f;
    let centre = (p + z * z / (2.0 * n_f)) / denom;
    let half = z * (p * (1.0 - p) / n_f + z * z / (4.0 * n_f * n_f)).sqrt() / denom;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

fn mean_ci(v: &[f64]) -> String {
    if v.is_empty() {
        return "-".into();
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return format!("{mean:.0}");
    }
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    format!("{mean:.0} ± {:.0}", 1.96 * sd / n.sqrt())
}

pub fn run(a: NavArgs) -> Result<()> {
    if a.list {
        for (method, graph) in METHODS {
            println!("{method}\t{graph}");
        }
        return Ok(());
    }
    let rows: Vec<(String, PathBuf)> = if a.graphs.is_empty() {
        METHODS
            .iter()
            .filter(|(m, _)| a.methods.is_empty() || a.methods.iter().any(|x| x == m))
            .map(|(m, g)| Ok((m.to_string(), crate::graph::repo_file(g)?)))
            .collect::<Result<_>>()?
    } else {
        a.graphs
            .iter()
            .map(|g| {
                let stem = g
                    .file_stem()
                    .map_or("graph".into(), |s| s.to_string_lossy());
                (stem.into_owned(), g.clone())
            })
            .collect()
    };
    let graphs: Vec<(String, Graph)> = rows
        .into_iter()
        .map(|(m, g)| Ok((m, Graph::load(&g)?)))
        .collect::<Result<_>>()?;
    println!(
        "navigation benchmark: {} seeded trials per cell, up to {:.0} s each, the shipped graphs in one process (one run, this machine):\n",
        a.trials, a.max_time_s
    );
    println!("| scenario | method | success [95% CI] | path m | time s | cost s | interventions |");
    println!("|---|---|---|---|---|---|---|");
    if let Some(d) = &a.trace {
        std::fs::create_dir_all(d)?;
    }
    let (mut frames, mut stage_steps, mut late, t0) = (0u64, 0u64, 0u64, Instant::now());
    for sc in &a.scenarios {
        for (m, graph) in &graphs {
            let mut runs = Vec::new();
            for seed in 1..=a.trials as u64 {
                let trace = a
                    .trace
                    .as_ref()
                    .map(|d| d.join(format!("{sc}-{m}-{seed}.csv")));
                let t = trial(graph, sc, seed, a.max_time_s, trace.as_deref())?;
                let s = &t.summary;
                eprintln!(
                    "  {sc} {m} seed {seed}: {:?} after {:.0} s, {:.0} m",
                    s.outcome, s.time_s, s.distance_m
                );
                frames += t.frames;
                stage_steps += t.stage_steps;
                late += t.late;
                runs.push(t.summary);
            }
            let ok: Vec<&Summary> = runs
                .iter()
                .filter(|s| s.outcome == Outcome::Reached)
                .collect();
            let (lo, hi) = wilson(ok.len(), runs.len());
            let pick = |f: fn(&Summary) -> f64| ok.iter().map(|s| f(s)).collect::<Vec<_>>();
            println!(
                "| {sc} | {m} | {:.0}% [{:.0}, {:.0}] | {} | {} | {} | {} |",
                100.0 * ok.len() as f64 / runs.len().max(1) as f64,
                100.0 * lo,
                100.0 * hi,
                mean_ci(&pick(|s| s.distance_m)),
                mean_ci(&pick(|s| s.time_s)),
                mean_ci(&pick(|s| s.traversal_cost_s)),
                mean_ci(
                    &runs
                        .iter()
                        .map(|s| s.interventions as f64)
                        .collect::<Vec<_>>()
                ),
            );
        }
    }
    let wall = t0.elapsed().as_secs_f64();
    println!(
        "\nsimulator + graph: {frames} steps in {wall:.1} s ({:.0} steps/s); {stage_steps} stage steps; {late} frames without a command",
        frames as f64 / wall
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_interval_by_hand() {
        let (lo, hi) = wilson(5, 10);
        assert!(
            (lo - 0.2366).abs() < 1e-3 && (hi - 0.7634).abs() < 1e-3,
            "{lo} {hi}"
        );
        let (lo, hi) = wilson(0, 5);
        assert_eq!(lo, 0.0);
        assert!(hi > 0.4 && hi < 0.5);
    }
}
