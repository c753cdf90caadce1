//! `farsight chaos`: motion safety under faults, measured. The simulator
//! drives the FITAM graph of `graphs/sim/chaos.toml` in real time (every
//! stage on the wall clock, camera frames stamped at capture, the servo
//! behind the command mux, as deployed), while this process kills (SIGKILL,
//! then a restart) and freezes (SIGSTOP, then SIGCONT) one random stage at
//! a time, and watches every topic that moves the robot:
//!
//! - **stale moving commands**: a moving command from the servo
//!   (`cmd/autonomy`) whose oldest capture was older than the servo's
//!   deadline (`subgoal_deadline_s` in the graph's servo config) when it was
//!   published; on `cmd/velocity` (the mux holds a command for the servo's
//!   `command_ttl_s`) older than deadline plus TTL. The publish time is
//!   bounded by this process's polls (a message first seen at poll t was
//!   published after the poll before), so a count is proven, never guessed;
//! - **self-exits**: a stage that ended without being killed;
//! - **restart to first output**: from the restart (or SIGCONT) to the
//!   stage's first new output message;
//! - **the robot stops while its command writer is down**: with the servo
//!   or the mux killed or frozen, the simulated robot's reported speed must
//!   reach zero within `--stop-deadline-s` and stay there;
//! - **distance made good** towards the goal, so a robot that never moves
//!   cannot pass.
//!
//! Each node is started (and restarted) with the command `farsight run`
//! would use for it (its inline config written to `<out>/<name>.toml`,
//! relative paths resolving against the graph file's folder), its stderr
//! appended to `<out>/<name>.log`. Faults go round the stages in shuffled
//! rounds, each a kill or a freeze at random, so a short run still faults
//! every stage. The test command runs two rounds (`tests/chaos.rs`); the
//! long run is `farsight chaos --faults 100`, which prints the table below
//! and writes `summary.toml`. It exits non-zero when an invariant fails.

use crate::demo::Stage;
use crate::graph::{Graph, NodeSpec};
use anyhow::{bail, Context, Result};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{NavGoal, Pose, VelocityCommand};
use farsight_interfaces::topics::{self, Topic};
use farsight_interfaces::transport::any::AnySubscriber;
use farsight_interfaces::transport::ipc::{Bus, IpcSettings, Subscriber};
use farsight_sim::rng::SplitMix64;
use farsight_velocity_servoing::stage::ServoStageConfig;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Debug, Clone, clap::Args)]
pub struct ChaosArgs {
    /// Faults to inject (kills and freezes, one stage at a time).
    #[arg(long, default_value_t = 100)]
    pub faults: u32,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, default_value = "bug-trap")]
    pub scenario: String,
    /// Output folder: configs, stage logs, summary.toml.
    #[arg(long, default_value = "out/chaos")]
    pub out: PathBuf,
    /// The simulator's image size (the FITAM model reads 160x96).
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    #[arg(long, default_value_t = 180)]
    pub height: u32,
    /// A killed or frozen stage's output must come back within this long.
    #[arg(long, default_value_t = 60.0)]
    pub resume_deadline_s: f64,
    /// The robot must have stopped this long after its command writer
    /// (servo or mux) went down: command TTL, deceleration and a margin.
    #[arg(long, default_value_t = 3.0)]
    pub stop_deadline_s: f64,
    /// Seconds between one stage's output resuming and the next fault, at
    /// most (uniformly from a quarter of it).
    #[arg(long, default_value_t = 3.0)]
    pub gap_s: f64,
}

/// The graph chaos runs, relative to the repository root.
const GRAPH: &str = "graphs/sim/chaos.toml";

/// The graph's nodes in start order, with the topic that shows each is working.
const STAGES: [(&str, &str); 6] = [
    ("inference", "perception/front/far_field"),
    ("bin-projection", "bins/polar"),
    ("costmap-fusion", "costmap/fused"),
    ("subgoal-selection", "nav/path/planned"),
    ("velocity-servoing", "cmd/autonomy"),
    ("command-mux", "cmd/velocity"),
];

#[derive(Debug, Clone, Copy, PartialEq)]
enum Fault {
    Kill,
    Freeze,
}

/// One stage process, restartable.
struct StageProc {
    name: &'static str,
    spec: NodeSpec,
    child: Option<Stage>,
    output: AnySubscriber,
}

/// One stage's faults and how fast its output came back.
#[derive(Debug, Default, Clone)]
pub struct StageRecord {
    pub name: String,
    pub kills: u32,
    pub freezes: u32,
    pub self_exits: u32,
    /// From the restart command to the first new output, per kill (s).
    pub restart_s: Vec<f64>,
    /// From SIGCONT to the first new output, per freeze (s).
    pub continue_s: Vec<f64>,
}

/// What the run measured.
#[derive(Debug, Default)]
pub struct ChaosReport {
    pub faults: u32,
    /// Per stage, in [`STAGES`] order.
    pub stages: Vec<StageRecord>,
    pub moving_commands: u64,
    pub stale_moving_servo: u64,
    pub stale_moving_mux: u64,
    /// The oldest capture behind a moving command at publish: the servo's
    /// (allowed: its deadline) and the mux's (allowed: deadline plus TTL).
    pub oldest_moving_servo_s: f64,
    pub oldest_moving_mux_s: f64,
    /// Per command-writer outage: seconds until the robot stood still
    /// (None: it never did before the writer came back).
    pub stops_s: Vec<Option<f64>>,
    /// Poses with the robot moving after it had stopped, writer still down.
    pub moved_while_down: u64,
    pub not_resumed: Vec<String>,
    /// Distance made good towards the goal, over every episode.
    pub made_good_m: f64,
    /// Episodes driven: the scenario starts again when the goal is reached.
    pub episodes: u32,
    pub wall_s: f64,
    /// The servo's stale-input deadline and command TTL in the graph: a
    /// moving command is stale on `cmd/autonomy` past the deadline, on
    /// `cmd/velocity` past deadline plus TTL.
    pub servo_deadline_s: f64,
    pub command_ttl_s: f64,
}

/// How much nearer the goal the robot got in an episode.
fn progress_m(goal: Option<[f64; 2]>, first: Option<[f64; 2]>, last: Option<&Pose>) -> Result<f64> {
    let goal = goal.context("the simulator published no goal")?;
    let (Some(first), Some(last)) = (first, last) else {
        return Ok(0.0);
    };
    let d = |p: [f64; 2]| (goal[0] - p[0]).hypot(goal[1] - p[1]);
    Ok(d(first) - d([last.position_m[0], last.position_m[1]]))
}

impl ChaosReport {
    pub fn distance_made_good_m(&self) -> f64 {
        self.made_good_m
    }

    pub fn self_exits(&self) -> u32 {
        self.stages.iter().map(|s| s.self_exits).sum()
    }

    /// The invariants, each failure named.
    pub fn failures(&self, stop_deadline_s: f64) -> Vec<String> {
        let mut f = Vec::new();
        if self.stale_moving_servo + self.stale_moving_mux > 0 {
            f.push(format!(
                "{} moving commands from stale sources (servo {}, mux {})",
                self.stale_moving_servo + self.stale_moving_mux,
                self.stale_moving_servo,
                self.stale_moving_mux
            ));
        }
        if self.self_exits() > 0 {
            f.push(format!("{} stages exited on their own", self.self_exits()));
        }
        for s in &self.not_resumed {
            f.push(format!("{s}: output did not resume"));
        }
        let late = self
            .stops_s
            .iter()
            .filter(|s| s.is_none_or(|t| t > stop_deadline_s))
            .count();
        if late > 0 {
            f.push(format!(
                "{late} of {} command-writer outages: the robot did not stop within {stop_deadline_s} s",
                self.stops_s.len()
            ));
        }
        if self.moved_while_down > 0 {
            f.push(format!(
                "the robot moved again {} times while its command writer was down",
                self.moved_while_down
            ));
        }
        if self.distance_made_good_m() < 5.0 {
            f.push(format!(
                "{:.1} m made good towards the goal (want at least 5 m)",
                self.distance_made_good_m()
            ));
        }
        f
    }

    /// The table `farsight chaos` prints.
    pub fn table(&self) -> String {
        let mut t = String::new();
        t += "| stage | kills | freezes | self-exits | restart to output, median / max (s) | continue to output, median / max (s) |\n";
        t += "|---|---|---|---|---|---|\n";
        for r in &self.stages {
            let (rm, rx) = median_max(&r.restart_s);
            let (cm, cx) = median_max(&r.continue_s);
            t += &format!(
                "| {} | {} | {} | {} | {rm} / {rx} | {cm} / {cx} |\n",
                r.name, r.kills, r.freezes, r.self_exits
            );
        }
        let stops: Vec<f64> = self.stops_s.iter().flatten().copied().collect();
        let (stop_median, stop_max) = median_max(&stops);
        t += &format!(
            "\nfaults {}; moving commands {}; stale moving commands: servo {}, mux {} \
             (oldest capture behind a moving command at publish: servo {:.2} s, allowed {} s; \
             mux {:.2} s, allowed {} s); \
             self-exits {}; robot stop after its command writer went down: median {} s, max {} s \
             over {} outages, {} never stopped, {} moved again while down; \
             distance made good {:.1} m over {} episodes in {:.0} s\n",
            self.faults,
            self.moving_commands,
            self.stale_moving_servo,
            self.stale_moving_mux,
            self.oldest_moving_servo_s,
            self.servo_deadline_s,
            self.oldest_moving_mux_s,
            self.servo_deadline_s + self.command_ttl_s,
            self.self_exits(),
            stop_median,
            stop_max,
            self.stops_s.len(),
            self.stops_s.iter().filter(|s| s.is_none()).count(),
            self.moved_while_down,
            self.distance_made_good_m(),
            self.episodes,
            self.wall_s
        );
        t
    }

    /// The summary as TOML (through the serializer).
    pub fn to_toml(&self) -> Result<String> {
        let mut root = toml::Table::new();
        let mut put = |k: &str, v: toml::Value| {
            root.insert(k.into(), v);
        };
        put("faults", (self.faults as i64).into());
        put("moving_commands", (self.moving_commands as i64).into());
        put(
            "stale_moving_servo",
            (self.stale_moving_servo as i64).into(),
        );
        put("stale_moving_mux", (self.stale_moving_mux as i64).into());
        put("oldest_moving_servo_s", self.oldest_moving_servo_s.into());
        put("oldest_moving_mux_s", self.oldest_moving_mux_s.into());
        put("self_exits", (self.self_exits() as i64).into());
        put("moved_while_down", (self.moved_while_down as i64).into());
        put(
            "stops_s",
            toml::Value::Array(
                self.stops_s
                    .iter()
                    .map(|s| s.unwrap_or(-1.0).into())
                    .collect(),
            ),
        );
        put("distance_made_good_m", self.distance_made_good_m().into());
        put("episodes", (self.episodes as i64).into());
        put("wall_s", self.wall_s.into());
        let mut stages = toml::Table::new();
        let seconds = |v: &[f64]| toml::Value::Array(v.iter().map(|&r| r.into()).collect());
        for r in &self.stages {
            let mut s = toml::Table::new();
            s.insert("kills".into(), (r.kills as i64).into());
            s.insert("freezes".into(), (r.freezes as i64).into());
            s.insert("self_exits".into(), (r.self_exits as i64).into());
            s.insert("restart_s".into(), seconds(&r.restart_s));
            s.insert("continue_s".into(), seconds(&r.continue_s));
            stages.insert(r.name.clone(), s.into());
        }
        root.insert("stages".into(), stages.into());
        Ok(toml::to_string(&root)?)
    }
}

fn median_max(v: &[f64]) -> (String, String) {
    if v.is_empty() {
        return ("-".into(), "-".into());
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    (
        format!("{:.3}", s[s.len() / 2]),
        format!("{:.3}", s[s.len() - 1]),
    )
}

/// The graph: every node of [`STAGES`] (and no other), each writing the
/// topic chaos watches it on, the servo behind the mux; and the servo's
/// deadline and command TTL from its config.
fn load_graph() -> Result<(Graph, PathBuf, ServoStageConfig)> {
    let path = std::path::absolute(crate::graph::repo_file(GRAPH)?)?;
    let graph = Graph::load(&path)?;
    let dir = path.parent().unwrap_or(Path::new("/")).to_path_buf();
    for n in &graph.nodes {
        let Some((_, topic)) = STAGES.iter().find(|s| s.0 == n.spec.name) else {
            bail!(
                "{}: node `{}` is not one chaos faults ({})",
                path.display(),
                n.spec.name,
                STAGES.map(|s| s.0).join(", ")
            );
        };
        if !n.io.writes.iter().any(|w| w == topic) {
            bail!(
                "{}: node `{}` does not write {topic}, the topic chaos watches it on",
                path.display(),
                n.spec.name
            );
        }
    }
    let servo = graph
        .nodes
        .iter()
        .find(|n| n.spec.name == "velocity-servoing")
        .with_context(|| format!("{}: no node `velocity-servoing`", path.display()))?;
    let servo: ServoStageConfig = match &servo.config_text {
        Some(text) => farsight_stage::parse_config(text, &servo.config_origin)?,
        None => ServoStageConfig::default(),
    };
    if servo.command_topic != "cmd/autonomy" {
        bail!(
            "{}: the servo writes {}; chaos runs it behind the command mux (command_topic = \"cmd/autonomy\")",
            path.display(),
            servo.command_topic
        );
    }
    Ok((graph, dir, servo))
}

/// Starts a node with `farsight run`'s command for it and waits for its
/// "ready" line; its log appends.
fn start(spec: &NodeSpec, graph_dir: &Path, prefix: &str, out: &Path) -> Result<Stage> {
    let name = &spec.name;
    let log = out.join(format!("{name}.log"));
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log)?;
    let child = crate::run::node_command(spec, graph_dir, out)?
        .env("FARSIGHT_IPC_PREFIX", prefix)
        .stdout(Stdio::piped())
        .stderr(file)
        .spawn()
        .with_context(|| format!("starting farsight-{}", spec.stage))?;
    let mut stage = Stage(child);
    let mut ready = String::new();
    BufReader::new(stage.0.stdout.take().expect("piped")).read_line(&mut ready)?;
    if ready.trim() != format!("{name} ready") {
        bail!(
            "farsight-{} did not start; see {}",
            spec.stage,
            log.display()
        );
    }
    Ok(stage)
}

fn signal(stage: &Stage, sig: libc::c_int) {
    // SAFETY: kill(2) on our own child's pid; no memory is involved.
    unsafe {
        libc::kill(stage.0.id() as libc::pid_t, sig);
    }
}

/// Where a fault stands.
enum Phase {
    /// Waiting until `at` to inject the next fault.
    Quiet { at: Instant },
    /// Stage `k` is down (killed or frozen) until `until`.
    Down {
        k: usize,
        fault: Fault,
        until: Instant,
    },
    /// Stage `k` is back (restarted or continued) at `since`; waiting for
    /// its first new output.
    Resuming {
        k: usize,
        fault: Fault,
        since: Instant,
    },
}

/// The robot's speed watch while its command writer is down.
struct Outage {
    since: Instant,
    stopped_at: Option<Instant>,
}

pub fn run(a: &ChaosArgs) -> Result<ChaosReport> {
    std::fs::create_dir_all(&a.out)?;
    let out = std::fs::canonicalize(&a.out)?;
    let prefix = std::env::var("FARSIGHT_IPC_PREFIX")
        .unwrap_or_else(|_| format!("chaos{}_", std::process::id()));
    // The stages inherit this process's environment (FARSIGHT_IPC_ROOT
    // included): the monitor must open the same iceoryx2 root.
    let mut settings = IpcSettings::from_env();
    settings.prefix = Some(prefix.clone());
    let (graph, graph_dir, servo) = load_graph()?;
    let (servo_deadline_s, command_ttl_s) = (servo.subgoal_deadline_s, servo.command_ttl_s);
    let bus = Bus::open_with("chaos", &settings)?;
    let mut stages = Vec::new();
    for (name, output_topic) in STAGES {
        let spec = graph
            .nodes
            .iter()
            .find(|n| n.spec.name == name)
            .map(|n| n.spec.clone())
            .with_context(|| format!("{GRAPH}: no node `{name}`"))?;
        let _ = std::fs::remove_file(out.join(format!("{name}.log")));
        let child = start(&spec, &graph_dir, &prefix, &out)?;
        stages.push(StageProc {
            name,
            spec,
            child: Some(child),
            output: AnySubscriber::open(&bus, output_topic)?,
        });
    }
    let servo_out: Subscriber<VelocityCommand> = bus.subscriber(&Topic::new("cmd/autonomy")?)?;
    let mux_out = bus.subscriber(&topics::velocity_command())?;
    let poses: Subscriber<Pose> = bus.subscriber(&topics::pose())?;
    let goals: Subscriber<NavGoal> = bus.subscriber(&topics::goal())?;

    // The simulator, in real time; a robot that reaches the goal starts
    // the scenario again (an episode), so the faults go on.
    let start_sim = |episode: u32| -> Result<Stage> {
        let sim_log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(out.join("sim.log"))?;
        let sim =
            crate::demo::die_with_parent(&mut Command::new(crate::demo::sibling("farsight-sim")?))
                .args(["run", "--clock", "realtime", "--scenario", &a.scenario])
                .args(["--seed", &a.seed.to_string(), "--max-time-s", "100000"])
                .args(["--width", &a.width.to_string()])
                .args(["--height", &a.height.to_string(), "--out"])
                .arg(out.join(format!("sim-{episode}")))
                .env("FARSIGHT_IPC_PREFIX", &prefix)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(sim_log)
                .spawn()
                .context("starting farsight-sim")?;
        Ok(Stage(sim))
    };
    let mut episode = 1;
    let mut sim = start_sim(episode)?;
    let mut made_good_m = 0.0;

    let mut rng = SplitMix64::new(a.seed ^ 0xc4a05);
    let mut report = ChaosReport {
        stages: STAGES
            .iter()
            .map(|(name, _)| StageRecord {
                name: name.to_string(),
                ..Default::default()
            })
            .collect(),
        servo_deadline_s,
        command_ttl_s,
        ..Default::default()
    };
    let start_wall = Instant::now();
    let mut goal: Option<[f64; 2]> = None;
    let mut first_pose: Option<[f64; 2]> = None;
    let mut last_pose: Option<Pose> = None;
    // Warm-up: the robot has to be driving before the first fault.
    let mut phase = Phase::Quiet {
        at: Instant::now() + Duration::from_secs(5),
    };
    let mut outage: Option<Outage> = None;
    let mut order: Vec<usize> = Vec::new();
    let mut last_poll = Instant::now();
    let mut done_at: Option<Instant> = None;
    let writer = |k: usize| matches!(STAGES[k].0, "velocity-servoing" | "command-mux");
    loop {
        let now = Instant::now();
        let now_ns = WallClock.now_ns();
        let gap_s = now.duration_since(last_poll).as_secs_f64();
        last_poll = now;

        // The commands: moving ones judged on their capture times. A
        // message first seen now was published after the previous poll, so
        // its age then was at least its age now minus the gap.
        let moving_age_s = |c: &VelocityCommand| {
            (c.linear_mps != 0.0 || c.angular_radps != 0.0)
                .then(|| now_ns.saturating_sub(c.stamp.capture_time_ns) as f64 * 1e-9 - gap_s)
        };
        for (sub, allowed_s, is_servo) in [
            (&servo_out, servo_deadline_s, true),
            (&mux_out, servo_deadline_s + command_ttl_s, false),
        ] {
            while let Some(c) = sub.latest()? {
                let Some(age_s) = moving_age_s(&c) else {
                    continue;
                };
                report.moving_commands += 1;
                let oldest = if is_servo {
                    &mut report.oldest_moving_servo_s
                } else {
                    &mut report.oldest_moving_mux_s
                };
                *oldest = oldest.max(age_s);
                if age_s > allowed_s {
                    tracing::warn!(age_s, ?c, is_servo, "moving command from a stale source");
                    if is_servo {
                        report.stale_moving_servo += 1;
                    } else {
                        report.stale_moving_mux += 1;
                    }
                }
            }
        }
        if let Some(g) = goals.latest()? {
            goal = Some([g.x_m, g.y_m]);
        }
        while let Some(p) = poses.latest()? {
            first_pose.get_or_insert([p.position_m[0], p.position_m[1]]);
            if let Some(o) = &mut outage {
                let moving = p.linear_mps.abs() > 0.01 || p.angular_radps.abs() > 0.01;
                match (o.stopped_at, moving) {
                    (None, false) => o.stopped_at = Some(now),
                    (Some(_), true) => report.moved_while_down += 1,
                    _ => {}
                }
            }
            last_pose = Some(p);
        }
        // Stages that ended on their own are counted and started again.
        for (k, s) in stages.iter_mut().enumerate() {
            let ended = s
                .child
                .as_mut()
                .is_some_and(|c| matches!(c.0.try_wait(), Ok(Some(_))));
            let is_down = matches!(phase, Phase::Down { k: d, fault: Fault::Kill, .. } if d == k);
            if ended && !is_down {
                report.stages[k].self_exits += 1;
                tracing::error!(stage = s.name, "exited on its own; restarting");
                s.child = Some(start(&s.spec, &graph_dir, &prefix, &out)?);
            }
        }
        // The fault schedule.
        phase = match phase {
            Phase::Quiet { at } if now >= at && done_at.is_none() => {
                if report.faults >= a.faults {
                    done_at = Some(now);
                    Phase::Quiet { at }
                } else {
                    // Rounds over every stage in a shuffled order, so a
                    // short run still faults each one.
                    if order.is_empty() {
                        order = (0..STAGES.len()).collect();
                        for i in (1..order.len()).rev() {
                            let j = (rng.unit() * (i + 1) as f64) as usize % (i + 1);
                            order.swap(i, j);
                        }
                    }
                    let k = order.pop().expect("refilled");
                    let fault = if rng.unit() < 0.5 {
                        Fault::Kill
                    } else {
                        Fault::Freeze
                    };
                    let s = &mut stages[k];
                    let child = s.child.as_ref().expect("running");
                    match fault {
                        Fault::Kill => {
                            signal(child, libc::SIGKILL);
                            report.stages[k].kills += 1;
                        }
                        Fault::Freeze => {
                            signal(child, libc::SIGSTOP);
                            report.stages[k].freezes += 1;
                        }
                    }
                    report.faults += 1;
                    eprintln!(
                        "fault {}/{}: {:?} {} ({:.0} s)",
                        report.faults,
                        a.faults,
                        fault,
                        s.name,
                        start_wall.elapsed().as_secs_f64()
                    );
                    if writer(k) {
                        outage = Some(Outage {
                            since: now,
                            stopped_at: None,
                        });
                    }
                    // A command writer stays down long enough for the robot
                    // to have to stop.
                    let down_s = if writer(k) {
                        a.stop_deadline_s + 0.5 + rng.unit()
                    } else {
                        0.5 + rng.unit() * 2.5
                    };
                    Phase::Down {
                        k,
                        fault,
                        until: now + Duration::from_secs_f64(down_s),
                    }
                }
            }
            Phase::Down {
                k, fault, until, ..
            } if now >= until => {
                let s = &mut stages[k];
                // Restart to first output counts the restart itself.
                let since = Instant::now();
                match fault {
                    Fault::Kill => {
                        // Reap the killed process, then start a new one.
                        if let Some(mut old) = s.child.take() {
                            let _ = old.0.wait();
                            // Dropping would signal a pid that is no longer
                            // ours; the handle holds no pipes (stdout taken).
                            std::mem::forget(old);
                        }
                        s.child = Some(start(&s.spec, &graph_dir, &prefix, &out)?);
                    }
                    Fault::Freeze => signal(s.child.as_ref().expect("running"), libc::SIGCONT),
                }
                // Messages from before the restart do not count as output.
                while s.output.take_wire()?.is_some() {}
                if let Some(o) = outage.take() {
                    report.stops_s.push(
                        o.stopped_at
                            .map(|t| t.duration_since(o.since).as_secs_f64()),
                    );
                }
                Phase::Resuming { k, fault, since }
            }
            Phase::Resuming { k, fault, since } => {
                if stages[k].output.take_wire()?.is_some() {
                    let resumed_s = since.elapsed().as_secs_f64();
                    let r = &mut report.stages[k];
                    match fault {
                        Fault::Kill => r.restart_s.push(resumed_s),
                        Fault::Freeze => r.continue_s.push(resumed_s),
                    }
                    let wait = a.gap_s * (0.25 + 0.75 * rng.unit());
                    Phase::Quiet {
                        at: Instant::now() + Duration::from_secs_f64(wait),
                    }
                } else if since.elapsed().as_secs_f64() > a.resume_deadline_s {
                    report.not_resumed.push(stages[k].name.to_string());
                    Phase::Quiet { at: Instant::now() }
                } else {
                    Phase::Resuming { k, fault, since }
                }
            }
            other => other,
        };
        // Drain the other stages' outputs so a resume is judged on new messages.
        for (k, s) in stages.iter().enumerate() {
            let resuming = matches!(phase, Phase::Resuming { k: r, .. } if r == k);
            if !resuming {
                while s.output.take_wire()?.is_some() {}
            }
        }
        if done_at.is_some_and(|t| t.elapsed() > Duration::from_secs(2)) {
            break;
        }
        if bus.termination_requested() {
            eprintln!("stopping early: termination requested");
            break;
        }
        if let Ok(Some(status)) = sim.0.try_wait() {
            if !status.success() {
                bail!(
                    "farsight-sim failed ({status}); see {}",
                    out.join("sim.log").display()
                );
            }
            // The goal is reached: count the episode's progress, drive it again.
            made_good_m += progress_m(goal, first_pose, last_pose.as_ref())?;
            (first_pose, last_pose) = (None, None);
            episode += 1;
            eprintln!("goal reached; episode {episode}");
            std::mem::forget(std::mem::replace(&mut sim, start_sim(episode)?));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    report.wall_s = start_wall.elapsed().as_secs_f64();
    drop(sim);
    for s in &mut stages {
        // A frozen stage would not hear SIGTERM.
        if let Some(c) = &s.child {
            signal(c, libc::SIGCONT);
        }
        s.child = None;
    }
    report.made_good_m = made_good_m + progress_m(goal, first_pose, last_pose.as_ref())?;
    report.episodes = episode;
    std::fs::write(out.join("summary.toml"), report.to_toml()?)?;
    Ok(report)
}

/// `farsight chaos`: runs, prints the table, fails on a broken invariant.
pub fn main(a: ChaosArgs) -> Result<()> {
    let report = run(&a)?;
    print!("{}", report.table());
    println!("summary, configs and logs in {}", a.out.display());
    let failures = report.failures(a.stop_deadline_s);
    if !failures.is_empty() {
        bail!(
            "motion safety under faults failed:\n- {}",
            failures.join("\n- ")
        );
    }
    Ok(())
}
