//! `farsight bench fitam`: FITAM's simulated evaluation as its paper ran it
//! (section V-A4, Table I), not the closed-loop drive of `farsight bench
//! nav`: random land-cover worlds (5 x 5 km by default), start/goal problems
//! at least 1 km apart, a kinematic sense-plan-act agent
//! (`farsight_sim::fitam_protocol`) per row, and the paper's paired
//! statistics against *No FF*: % of trials improved, average % cost
//! difference, % failed (failures excluded from the pairing).
//!
//! The far-field filter's constants come from the shipped graph
//! (`graphs/sim/fitam-gt.toml`'s costmap-fusion node), so the protocol
//! plans on the map the graph would build. Rows: *No FF*, *GT FF* (labels
//! from the true world over a full 360 degrees, as the paper's panoramas),
//! *Learned FF* (the shipped far-field model of `graphs/sim/fitam.toml` on
//! a rig of four 120 degree cameras all round the robot,
//! [`crate::fitam_rig`]), *Perfect Vision* (local observations out to
//! 100 m).
//!
//! Decided before measured (issue 20, item 7), with `bench nav`'s
//! bookkeeping ([`crate::bench_record`]): the [`FitamProtocol`] (world
//! generator and agent-rule versions, every trial parameter, the graph
//! file's SHA-256) is hashed into the results file (`--out FILE.json`,
//! rewritten after every problem); `--shard K/N` runs every N-th world, and
//! `farsight bench fitam-merge` joins the shards' files, refusing mixed
//! versions, parameters, graphs or commits.

use crate::bench_record::{self as record, Decided, Keyed, MethodGraph, Results, Shard};
use crate::fitam_rig::{LearnedGraph, LearnedRig};
use crate::graph::Graph;
use anyhow::{bail, Context, Result};
use clap::Args;
use farsight_costmap_fusion::stage::FusionStageConfig;
use farsight_sim::fitam_protocol::{
    paired_against, sample_problems, sense_plan_act, FarFieldSource, MeanCi, ProtocolConfig, Row,
};
use farsight_sim::scenario::random_world;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

#[derive(Args, Debug, Clone)]
pub struct FitamArgs {
    /// Random worlds (seeds 1..=N).
    #[arg(long, default_value_t = 4)]
    pub maps: usize,
    /// Start/goal problems per world (the paper: 100).
    #[arg(long, default_value_t = 25)]
    pub problems_per_map: usize,
    /// World side in metres (the paper: 5000).
    #[arg(long, default_value_t = 5000)]
    pub size_m: usize,
    /// Least straight-line distance from start to goal (the paper: 1000 m).
    #[arg(long, default_value_t = 1000.0)]
    pub min_goal_m: f64,
    /// Start and goal at least this far from the world's edge (100 m, as
    /// the reference code).
    #[arg(long, default_value_t = 100.0)]
    pub edge_margin_m: f64,
    /// Rows to run besides No FF (default: all).
    #[arg(long, value_delimiter = ',')]
    pub rows: Vec<String>,
    /// Worker threads (default: the machine's cores). Each holds about
    /// 1.3 GB on a 5 x 5 km world.
    #[arg(long)]
    pub jobs: Option<usize>,
    /// The graph whose costmap-fusion config the map uses.
    #[arg(long, default_value = "graphs/sim/fitam-gt.toml")]
    pub graph: PathBuf,
    /// The learned row's graph: its inference node's far-field model and
    /// its bin-projection node's FITAM bins.
    #[arg(long, default_value = "graphs/sim/fitam.toml")]
    pub learned_graph: PathBuf,
    /// The learned row's cameras, all round the robot (the simulator's
    /// mounts: front, left, right, rear; 120 degrees each).
    #[arg(long, value_delimiter = ',', default_value = "front,left,right,rear")]
    pub rig: Vec<String>,
    /// Run only the K-th of N parts of the worlds (world k is in part
    /// ((k - 1) mod N) + 1), e.g. one per array job.
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Write the results (commit, versions, protocol hash, shard, each
    /// trial) to this JSON file, rewritten after every problem.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Everything decided before a `bench fitam` trial is run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitamProtocol {
    /// `farsight_sim::scenario::WORLD_GENERATOR_VERSION`.
    pub world_generator: u32,
    /// `farsight_sim::fitam_protocol::AGENT_RULES_VERSION`.
    pub agent_rules: u32,
    pub maps: usize,
    pub problems_per_map: usize,
    pub size_m: usize,
    pub min_goal_m: f64,
    pub edge_margin_m: f64,
    /// Row names, No FF first.
    pub rows: Vec<String>,
    /// The graph the far-field filter's constants come from.
    pub graph: MethodGraph,
    /// The learned row's graph, model file and cameras, when it runs.
    #[serde(default)]
    pub learned: Option<LearnedProtocol>,
}

/// What the learned row's numbers depend on besides the agent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LearnedProtocol {
    pub graph: MethodGraph,
    /// The ONNX file its model config names.
    pub model: MethodGraph,
    pub rig: Vec<String>,
}

/// One trial of the list: world seed, problem and row.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct FitamKey {
    pub map_seed: u64,
    pub problem: usize,
    pub row: String,
}

impl fmt::Display for FitamKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "world {} problem {} {}",
            self.map_seed, self.problem, self.row
        )
    }
}

impl Decided for FitamProtocol {
    type Key = FitamKey;

    fn fields(&self) -> Vec<(&'static str, String)> {
        vec![
            ("protocol.world_generator", self.world_generator.to_string()),
            ("protocol.agent_rules", self.agent_rules.to_string()),
            (
                "protocol.maps / problems_per_map / size_m",
                format!(
                    "{} / {} / {}",
                    self.maps, self.problems_per_map, self.size_m
                ),
            ),
            (
                "protocol.min_goal_m / edge_margin_m",
                format!("{} / {}", self.min_goal_m, self.edge_margin_m),
            ),
            ("protocol.rows", format!("{:?}", self.rows)),
            ("protocol.graph (path, hash)", format!("{:?}", self.graph)),
            (
                "protocol.learned (graph, model, rig)",
                format!("{:?}", self.learned),
            ),
        ]
    }

    /// Per world, per problem, per row.
    fn trial_list(&self) -> Vec<FitamKey> {
        let mut out = Vec::new();
        for map_seed in 1..=self.maps as u64 {
            for problem in 0..self.problems_per_map {
                for row in &self.rows {
                    out.push(FitamKey {
                        map_seed,
                        problem,
                        row: row.clone(),
                    });
                }
            }
        }
        out
    }
}

impl Keyed for TrialLine {
    type Key = FitamKey;

    fn key(&self) -> FitamKey {
        FitamKey {
            map_seed: self.map_seed,
            problem: self.problem,
            row: self.row.clone(),
        }
    }
}

/// `farsight bench fitam`'s results file.
pub type FitamResults = Results<FitamProtocol, TrialLine>;

/// One trial's outcome.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct TrialLine {
    pub map_seed: u64,
    pub problem: usize,
    pub row: String,
    pub straight_line_m: f64,
    pub oracle_cost_s: f64,
    pub reached: bool,
    pub cost_s: f64,
    pub distance_m: f64,
    pub iterations: usize,
}

/// The graph file at `graph_path`, or the repository's file of that name.
fn graph_file(graph_path: &Path) -> Result<PathBuf> {
    if graph_path.is_relative() && !graph_path.exists() {
        crate::graph::repo_file(&graph_path.to_string_lossy())
    } else {
        Ok(graph_path.to_path_buf())
    }
}

/// The far-field filter constants of the graph's costmap-fusion node.
fn protocol_config(graph_path: &Path) -> Result<ProtocolConfig> {
    let path = graph_file(graph_path)?;
    let graph = Graph::load(&path)?;
    let Some(node) = graph
        .nodes
        .iter()
        .find(|n| n.spec.stage == "costmap-fusion")
    else {
        bail!(
            "{}: no costmap-fusion node, so no far-field filter to evaluate",
            path.display()
        );
    };
    let fusion: FusionStageConfig = match &node.config_text {
        Some(text) => farsight_stage::parse_config(text, &node.config_origin)?,
        None => FusionStageConfig::default(),
    };
    Ok(ProtocolConfig {
        far_field: fusion.far_field,
        ..ProtocolConfig::default()
    })
}

fn rows(names: &[String]) -> Result<Vec<Row>> {
    let mut out = vec![Row::NoFarField];
    if names.is_empty() {
        out.extend(Row::ALL.into_iter().filter(|r| *r != Row::NoFarField));
        return Ok(out);
    }
    for n in names {
        let Some(r) = Row::from_name(n) else {
            let known: Vec<&str> = Row::ALL.iter().map(|r| r.name()).collect();
            bail!("unknown row {n:?}; known: {}", known.join(", "));
        };
        if !out.contains(&r) {
            out.push(r);
        }
    }
    Ok(out)
}

/// The paper's numbers (Table I) beside ours.
fn paper(row: Row) -> &'static str {
    match row {
        Row::NoFarField => "failed 0.71%",
        Row::GroundTruthFarField => "92.5 ± 0.4 / 19.2 ± 0.3 / 0.72",
        Row::LearnedFarField => "92.5 ± 0.4 / 19.1 ± 0.3 / 0.74",
        Row::PerfectVision => "95.7 ± 0.3 / 24.7 ± 0.3 / 0.33",
    }
}

fn ci(m: Option<MeanCi>) -> String {
    match m {
        None => "-".into(),
        Some(m) if m.half_width.is_nan() => format!("{:.1}", m.mean),
        Some(m) => format!("{:.1} ± {:.1}", m.mean, m.half_width),
    }
}

/// The table of Table I's statistics from trial lines (any order).
pub fn table(lines: &[TrialLine], rows: &[Row]) -> String {
    use std::collections::BTreeMap;
    // Problem key -> row -> cost (None = failed).
    let mut by_problem: BTreeMap<(u64, usize), BTreeMap<&str, Option<f64>>> = BTreeMap::new();
    let mut oracle: BTreeMap<(u64, usize), f64> = BTreeMap::new();
    for l in lines {
        by_problem
            .entry((l.map_seed, l.problem))
            .or_default()
            .insert(l.row.as_str(), l.reached.then_some(l.cost_s));
        oracle.insert((l.map_seed, l.problem), l.oracle_cost_s);
    }
    let column = |row: Row| -> Vec<Option<f64>> {
        by_problem
            .values()
            .map(|m| m.get(row.name()).copied().flatten())
            .collect()
    };
    let base = column(Row::NoFarField);
    let mut out = String::from(
        "| row | trials | % trials improved | avg % diff | % failed | cost / oracle | paper: improved / diff / failed |\n|---|---|---|---|---|---|---|\n",
    );
    for &row in rows {
        let costs = column(row);
        let stats = paired_against(&base, &costs);
        let over_oracle: Vec<f64> = by_problem
            .iter()
            .zip(&costs)
            .filter_map(|((k, _), c)| c.map(|c| c / oracle[k]))
            .collect();
        let (improved, diff) = if row == Row::NoFarField {
            ("-".to_string(), "-".to_string())
        } else {
            (ci(stats.trials_improved_pct), ci(stats.avg_diff_pct))
        };
        out += &format!(
            "| {} | {} | {improved} | {diff} | {:.2} | {} | {} |\n",
            row.name(),
            costs.len(),
            stats.failed_pct,
            MeanCi::of(&over_oracle).map_or("-".into(), |m| format!("{:.2}", m.mean)),
            paper(row),
        );
    }
    out
}

/// The first lines of a table: what was measured, under which rules.
pub fn header(f: &FitamResults) -> String {
    let p = &f.protocol;
    format!(
        "FITAM protocol (section V-A4): {} worlds of {} m, {} problems each (start/goal >= {} m apart, >= {} m from the edge), rows {}\nprotocol {} (world generator v{}, agent rules v{}, far field of {}), commit {}{}\n",
        p.maps,
        p.size_m,
        p.problems_per_map,
        p.min_goal_m,
        p.edge_margin_m,
        p.rows.join(", "),
        &f.protocol_hash[..16.min(f.protocol_hash.len())],
        p.world_generator,
        p.agent_rules,
        p.graph.graph,
        f.commit,
        if f.dirty { " (with uncommitted changes)" } else { "" },
    )
}

/// A results file's rows, parsed back (a merge of files from this build).
fn rows_of(f: &FitamResults) -> Result<Vec<Row>> {
    f.protocol
        .rows
        .iter()
        .map(|n| Row::from_name(n).ok_or_else(|| anyhow::anyhow!("unknown row {n:?} in the file")))
        .collect()
}

/// `farsight bench fitam-merge`: prints the table of the whole run.
pub fn run_merge(a: record::MergeArgs) -> Result<()> {
    let merged: FitamResults = a.merge()?;
    print!(
        "{}\n{}",
        header(&merged),
        table(&merged.trials, &rows_of(&merged)?)
    );
    Ok(())
}

/// Refuses arguments that would sample nothing or everything, naming the flag.
fn check_args(a: &FitamArgs) -> Result<()> {
    if a.maps == 0 || a.problems_per_map == 0 {
        bail!("--maps and --problems-per-map must be at least 1");
    }
    if a.size_m < 50 || a.size_m > 5000 {
        bail!("--size-m {} is outside 50..=5000", a.size_m);
    }
    for (flag, v) in [
        ("--min-goal-m", a.min_goal_m),
        ("--edge-margin-m", a.edge_margin_m),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{flag} {v} is not a finite distance >= 0 m");
        }
    }
    Ok(())
}

/// The protocol of a run with these arguments.
fn protocol(a: &FitamArgs, rows: &[Row], learned: Option<&LearnedGraph>) -> Result<FitamProtocol> {
    let path = graph_file(&a.graph)?;
    let learned = match learned {
        Some(l) => Some(LearnedProtocol {
            graph: MethodGraph::read(
                "learned_far_field",
                &a.learned_graph.to_string_lossy(),
                &graph_file(&a.learned_graph)?,
            )?,
            model: MethodGraph::read("model", &l.model_file.to_string_lossy(), &l.model_file)?,
            rig: a.rig.clone(),
        }),
        None => None,
    };
    Ok(FitamProtocol {
        world_generator: farsight_sim::scenario::WORLD_GENERATOR_VERSION,
        agent_rules: farsight_sim::fitam_protocol::AGENT_RULES_VERSION,
        maps: a.maps,
        problems_per_map: a.problems_per_map,
        size_m: a.size_m,
        min_goal_m: a.min_goal_m,
        edge_margin_m: a.edge_margin_m,
        rows: rows.iter().map(|r| r.name().to_string()).collect(),
        graph: MethodGraph::read("far_field_filter", &a.graph.to_string_lossy(), &path)?,
        learned,
    })
}

/// The learned row's graph, checked against the protocol's geometry and
/// far-field filter (every row is fused by one filter, or the pairing
/// would compare filters too).
fn learned_graph(a: &FitamArgs, cfg: &ProtocolConfig) -> Result<LearnedGraph> {
    let path = graph_file(&a.learned_graph)?;
    let own = protocol_config(&a.learned_graph)?;
    if own.far_field != cfg.far_field {
        bail!(
            "{}'s costmap-fusion far-field filter differs from {}'s: {:?} vs {:?}",
            path.display(),
            a.graph.display(),
            own.far_field,
            cfg.far_field
        );
    }
    if a.rig.is_empty() {
        bail!("--rig: name at least one camera");
    }
    for name in &a.rig {
        farsight_sim::run::named_camera(name, 1, 1).context("--rig")?;
    }
    LearnedGraph::load(&path, &cfg.geometry)
}

pub fn run(a: FitamArgs) -> Result<()> {
    check_args(&a)?;
    let cfg = protocol_config(&a.graph)?;
    let rows = rows(&a.rows)?;
    let learned = match rows.contains(&Row::LearnedFarField) {
        true => Some(learned_graph(&a, &cfg)?),
        false => None,
    };
    let shard = a.shard.unwrap_or(Shard::ALL);
    let results = FitamResults::start(protocol(&a, &rows, learned.as_ref())?, shard);
    // World k (0-based) is shard (k mod N) + 1's: whole worlds, as each
    // costs a generation and a gigabyte.
    let maps: Vec<u64> = (0..a.maps)
        .filter(|&k| shard.holds(k))
        .map(|k| k as u64 + 1)
        .collect();
    let jobs = a
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .clamp(1, maps.len().max(1));
    print!("{}", header(&results));
    println!("shard {shard}: worlds {maps:?}, {jobs} threads (one run, this machine)\n");
    if let Some(out) = &a.out {
        // Written now, so a bad path fails before any trial is run.
        record::write(out, &results)?;
    }
    let t0 = Instant::now();
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let results = Mutex::new(results);
    let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    let fail = |e: anyhow::Error| {
        stop.store(true, Ordering::Relaxed);
        failure.lock().expect("no panics hold it").get_or_insert(e);
    };
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| {
                let mut rig: Option<LearnedRig> = None;
                loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                if k >= maps.len() || stop.load(Ordering::Relaxed) {
                    return;
                }
                let seed = maps[k];
                // One model session per thread, loaded with its first world.
                if rig.is_none() {
                    if let Some(l) = &learned {
                        match LearnedRig::new(l, &a.rig) {
                            Ok(r) => rig = Some(r),
                            Err(e) => return fail(e),
                        }
                    }
                }
                let world = random_world(seed, a.size_m).world;
                let problems =
                    sample_problems(&world, a.problems_per_map, a.min_goal_m, a.edge_margin_m, seed);
                if problems.len() < a.problems_per_map {
                    // The trial list was decided with problems_per_map per world.
                    return fail(anyhow::anyhow!(
                        "world {seed} holds only {} problems >= {} m apart (--problems-per-map {}): lower --problems-per-map or --min-goal-m, or raise --size-m",
                        problems.len(),
                        a.min_goal_m,
                        a.problems_per_map
                    ));
                }
                for (i, p) in problems.iter().enumerate() {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    let mut mine = Vec::new();
                    for &row in &rows {
                        let t = Instant::now();
                        let source = rig.as_mut().map(|r| r as &mut dyn FarFieldSource);
                        let r = match sense_plan_act(&world, p, row, &cfg, source) {
                            Ok(r) => r,
                            Err(e) => {
                                return fail(e.context(format!("world {seed} problem {i} {}", row.name())))
                            }
                        };
                        eprintln!(
                            "  world {seed} problem {i} {}: {} cost {:.0} s ({:.2} x oracle), {:.0} m, {} iterations, {:.1} s",
                            row.name(),
                            if r.reached { "reached" } else { "FAILED" },
                            r.cost_s,
                            r.cost_s / p.oracle_cost_s,
                            r.distance_m,
                            r.iterations,
                            t.elapsed().as_secs_f64()
                        );
                        mine.push(TrialLine {
                            map_seed: seed,
                            problem: i,
                            row: row.name().into(),
                            straight_line_m: p.straight_line_m(world.resolution_m),
                            oracle_cost_s: p.oracle_cost_s,
                            reached: r.reached,
                            cost_s: r.cost_s,
                            distance_m: r.distance_m,
                            iterations: r.iterations,
                        });
                    }
                    let mut res = results.lock().expect("no panics hold it");
                    res.trials.extend(mine);
                    // In the trial list's order, as a merge gives them.
                    res.trials.sort_by_key(|t| {
                        (t.map_seed, t.problem, rows.iter().position(|r| r.name() == t.row))
                    });
                    if let Some(out) = &a.out {
                        if let Err(e) = record::write(out, &*res) {
                            return fail(e);
                        }
                    }
                }
                }
            });
        }
    });
    if let Some(e) = failure.into_inner().expect("no panics hold it") {
        return Err(e);
    }
    let results = results.into_inner().expect("no panics hold it");
    print!("{}", table(&results.trials, &rows));
    println!(
        "\n{} trials in {:.0} s. Paired over the problems both No FF and the row reached; ± is the 95% interval (1.96 standard errors), as Table I.",
        results.trials.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(map_seed: u64, problem: usize, row: Row, cost: Option<f64>) -> TrialLine {
        TrialLine {
            map_seed,
            problem,
            row: row.name().into(),
            straight_line_m: 1000.0,
            oracle_cost_s: 100.0,
            reached: cost.is_some(),
            cost_s: cost.unwrap_or(9999.0),
            distance_m: 1000.0,
            iterations: 10,
        }
    }

    #[test]
    fn the_table_pairs_by_problem_and_reports_failures_apart() {
        let rows = [Row::NoFarField, Row::GroundTruthFarField];
        let lines = vec![
            line(1, 0, Row::GroundTruthFarField, Some(150.0)),
            line(1, 0, Row::NoFarField, Some(200.0)),
            line(1, 1, Row::NoFarField, Some(300.0)),
            line(1, 1, Row::GroundTruthFarField, Some(300.0)),
            line(2, 0, Row::NoFarField, Some(400.0)),
            line(2, 0, Row::GroundTruthFarField, None),
        ];
        let t = table(&lines, &rows);
        let gt = t.lines().find(|l| l.starts_with("| gt_far_field")).unwrap();
        // Paired: problems (1,0) and (1,1): improved 1 of 2; diffs 25% and 0%.
        assert!(gt.contains("| 50.0 ± 98.0 | 12.5 ± 24.5 | 33.33 |"), "{gt}");
        let noff = t.lines().find(|l| l.starts_with("| no_far_field")).unwrap();
        assert!(noff.contains("| 0.00 | 3.00 |"), "{noff}");
    }

    #[test]
    fn bad_arguments_are_refused_by_name() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            a: FitamArgs,
        }
        let parse = |args: &[&str]| Cli::try_parse_from([&["x"], args].concat()).unwrap().a;
        assert!(check_args(&parse(&[])).is_ok());
        let e = check_args(&parse(&["--min-goal-m", "nan"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--min-goal-m NaN"), "{e}");
        let e = check_args(&parse(&["--edge-margin-m=-5"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--edge-margin-m -5"), "{e}");
        let e = check_args(&parse(&["--size-m", "9000"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--size-m 9000"), "{e}");
        assert!(check_args(&parse(&["--maps", "0"])).is_err());
    }

    #[test]
    fn shards_of_worlds_merge_into_the_unsharded_run_and_mixed_files_are_refused() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            a: FitamArgs,
        }
        let dir =
            std::env::temp_dir().join(format!("farsight-fitam-shards-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let run_to = |name: &str, extra: &[&str]| -> FitamResults {
            let out = dir.join(name);
            let small = [
                "x",
                "--maps",
                "3",
                "--problems-per-map",
                "2",
                "--size-m",
                "300",
                "--min-goal-m",
                "150",
                "--edge-margin-m",
                "20",
                "--rows",
                "gt_far_field",
                "--jobs",
                "1",
                "--out",
            ];
            let args: Vec<&str> = [&small[..], &[out.to_str().unwrap()], extra].concat();
            run(Cli::try_parse_from(args).unwrap().a).unwrap();
            record::read(&out).unwrap()
        };
        let whole = run_to("whole.json", &[]);
        assert_eq!(
            whole.trials.len(),
            3 * 2 * 2,
            "every trial, written as it ran"
        );
        assert_eq!(whole.protocol_hash, whole.protocol.hash());
        let parts: Vec<(PathBuf, FitamResults)> = (1..=2)
            .map(|k| {
                let name = format!("part{k}.json");
                let f = run_to(&name, &["--shard", &format!("{k}/2")]);
                (dir.join(name), f)
            })
            .collect();
        // Whole worlds per shard: 1 and 3 in the first, 2 in the second.
        let worlds = |f: &FitamResults| {
            let mut w: Vec<u64> = f.trials.iter().map(|t| t.map_seed).collect();
            w.dedup();
            w
        };
        assert_eq!(worlds(&parts[0].1), [1, 3]);
        assert_eq!(worlds(&parts[1].1), [2]);
        let merged = record::merge(&parts).unwrap();
        assert_eq!(
            merged.trials, whole.trials,
            "the same trials, deterministic"
        );
        assert_eq!(
            table(&merged.trials, &rows_of(&merged).unwrap()),
            table(&whole.trials, &rows_of(&whole).unwrap())
        );
        // A shard from other agent rules is refused, by file and field.
        let mut newer = parts[1].clone();
        newer.1.protocol.agent_rules += 1;
        newer.1.protocol_hash = newer.1.protocol.hash();
        let e = record::merge(&[parts[0].clone(), newer])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("part2.json") && e.contains("protocol.agent_rules"),
            "{e}"
        );
        let e = record::merge(&parts[..1]).unwrap_err().to_string();
        assert!(e.contains("4 of 12 trials") && e.contains("world 2"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Needs ONNX Runtime (`ORT_DYLIB_PATH`), as the inference tests.
    #[test]
    fn the_learned_row_runs_the_graphs_model_on_the_rig_and_hashes_it() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            a: FitamArgs,
        }
        let dir =
            std::env::temp_dir().join(format!("farsight-fitam-learned-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("learned.json");
        let args = [
            "x",
            "--maps",
            "1",
            "--problems-per-map",
            "1",
            "--size-m",
            "300",
            "--min-goal-m",
            "150",
            "--edge-margin-m",
            "20",
            "--rows",
            "learned_far_field",
            "--rig",
            "front,rear",
            "--out",
            out.to_str().unwrap(),
        ];
        run(Cli::try_parse_from(args).unwrap().a).unwrap();
        let f: FitamResults = record::read(&out).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        let rows: Vec<&str> = f.trials.iter().map(|t| t.row.as_str()).collect();
        assert_eq!(rows, ["no_far_field", "learned_far_field"]);
        assert!(f.trials.iter().all(|t| t.reached), "{:?}", f.trials);
        let learned = f
            .protocol
            .learned
            .as_ref()
            .expect("the learned row is recorded");
        assert_eq!(learned.rig, ["front", "rear"]);
        assert_eq!(learned.graph.graph, "graphs/sim/fitam.toml");
        let model = crate::graph::repo_file("deploy/models/sim-fitam/model.onnx").unwrap();
        let bytes = std::fs::read(model).unwrap();
        assert_eq!(learned.model.sha256, record::sha256_hex(&bytes));
        // A rig camera the simulator does not mount is refused by name.
        let bad =
            Cli::try_parse_from(
                args.iter()
                    .map(|a| if *a == "front,rear" { "front,top" } else { a }),
            )
            .unwrap()
            .a;
        let e = format!("{:#}", run(bad).unwrap_err());
        assert!(e.contains("unknown camera \"top\""), "{e}");
    }

    #[test]
    fn rows_are_named_and_checked() {
        assert_eq!(rows(&[]).unwrap().len(), 4);
        assert_eq!(
            rows(&["perfect_vision".into()]).unwrap(),
            vec![Row::NoFarField, Row::PerfectVision]
        );
        let e = rows(&["gt".into()]).unwrap_err().to_string();
        assert!(e.contains("\"gt\"") && e.contains("gt_far_field"), "{e}");
    }

    #[test]
    fn the_far_field_filter_is_the_graphs() {
        let shipped = crate::graph::repo_file("graphs/sim/fitam-gt.toml").unwrap();
        let cfg = protocol_config(&shipped).unwrap();
        assert_eq!(cfg.far_field, FusionStageConfig::default().far_field);
        // The same graph with its fusion node's process noise changed: the
        // protocol plans with the changed filter.
        let text = std::fs::read_to_string(&shipped).unwrap();
        let changed = text.replacen(
            "[[node]]\nname = \"subgoal-selection\"",
            "[node.config.far_field]\nprocess_noise = 0.005\n\n[[node]]\nname = \"subgoal-selection\"",
            1,
        );
        assert_ne!(changed, text, "the shipped graph's layout changed");
        let dir = std::env::temp_dir().join(format!("farsight-bench-fitam-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("fitam-gt.toml");
        std::fs::write(&path, changed).unwrap();
        let cfg = protocol_config(&path).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(cfg.far_field.process_noise, 0.005);
        assert_eq!((cfg.max_iterations, cfg.max_travel_m), (1000, 20.0));
    }
}
