//! The graph as data: a graph file (`graphs/*.toml`) names stage instances,
//! their stage kind, config (a file or inline), machine and restart policy;
//! the edges are computed from what each stage kind declares it reads and
//! writes given its config (`farsight_stage::DeclaresTopics`), as dora-rs
//! and copper-rs keep the graph in one file.
//!
//! ```toml
//! description = "The robot computer: POVNav on the front camera."
//!
//! [[node]]
//! name = "inference-front"          # the instance: health/<name>, logs, inspect rows
//! stage = "inference"               # the stage kind (farsight-<stage>)
//! config = "../deploy/config/inference.toml"   # relative to this file; or [node.config]
//! machine = "robot"                 # default "robot"
//! restart = "on-failure"            # "no", "on-failure" (default) or "always"
//!
//! [[external]]                      # written outside the graph
//! topic = "state/pose"
//! from = "the base's odometry driver"
//! ```
//!
//! `farsight graph check GRAPH` loads every node's config as its stage
//! would (unknown keys and out-of-range values are errors naming the node),
//! then fails naming node and topic for a required input nothing writes, two
//! writers of one topic, a name that is not a farsight topic, an unknown
//! stage kind, or more publishers or subscribers on a topic than the
//! shared-memory transport allows on one machine. It prints the node and
//! topic tables and writes the graph as Mermaid or DOT.

use anyhow::{bail, Context, Result};
use farsight_interfaces::topics::{self, TopicKind};
use farsight_interfaces::transport::ipc::{
    segment_samples, MAX_PUBLISHERS, MAX_SUBSCRIBERS, QUEUE_SUBSCRIBERS,
};
use farsight_stage::{DeclaresTopics, Io, Need, Validate};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A stage kind a graph node may name: how its config is loaded and what
/// it then reads and writes, and how an instance is built in this process
/// (the in-process executor; `None` for kinds that only run as processes:
/// a camera driver, the zenoh bridge).
pub struct StageKindEntry {
    pub kind: &'static str,
    pub io: LoadIo,
    pub build: Option<BuildStage>,
}

/// A kind that runs only as its own process.
const fn process_only(kind: &'static str, io: LoadIo) -> StageKindEntry {
    StageKindEntry {
        kind,
        io,
        build: None,
    }
}

/// A kind with a stage library type: runs as a process or in one.
const fn stage<S>() -> StageKindEntry
where
    S: farsight_stage::StageKind + 'static,
    S::Config: DeclaresTopics,
{
    StageKindEntry {
        kind: S::KIND,
        io: load_io::<S::Config>,
        build: Some(build::<S>),
    }
}

/// Every stage kind, once: graph checks, `farsight run` and the
/// in-process executor all look kinds up here.
pub const STAGE_KINDS: [StageKindEntry; 9] = [
    process_only(
        "camera-ingest",
        load_io::<farsight_camera_ingest::IngestConfig>,
    ),
    stage::<farsight_inference::inference_stage::InferenceStage>(),
    stage::<farsight_bin_projection::projection_stage::ProjectionStage>(),
    stage::<farsight_costmap_fusion::fusion_stage::FusionStage>(),
    stage::<farsight_subgoal_selection::subgoal_stage::SubgoalStage>(),
    stage::<farsight_velocity_servoing::servo_stage::ServoStage>(),
    stage::<farsight_command_mux::mux_stage::MuxStage>(),
    process_only("bridge", load_io::<farsight_bridge::BridgeConfig>),
    process_only(
        "recorder",
        load_io::<farsight_recording::node::RecorderConfig>,
    ),
];

/// Builds an instance of a stage kind in this process from its config text
/// (`None`: the defaults).
pub type BuildStage = fn(
    instance: &str,
    text: Option<&str>,
    origin: &str,
    dir: &Path,
) -> Result<Box<dyn farsight_stage::Stage>>;

fn parse_or_default<T: DeserializeOwned + Validate + Default>(
    text: Option<&str>,
    origin: &str,
) -> Result<T, farsight_stage::ConfigError> {
    match text {
        Some(t) => farsight_stage::parse_config(t, origin),
        None => {
            let c = T::default();
            c.validate()?;
            Ok(c)
        }
    }
}

fn build<S: farsight_stage::StageKind + 'static>(
    instance: &str,
    text: Option<&str>,
    origin: &str,
    dir: &Path,
) -> Result<Box<dyn farsight_stage::Stage>> {
    let config: S::Config = parse_or_default(text, origin)?;
    let env = farsight_stage::StageEnv {
        instance: instance.to_string(),
        config_dir: dir.to_path_buf(),
    };
    let stage = S::new(config, &env).with_context(|| format!("node `{instance}`"))?;
    Ok(Box::new(stage))
}

/// Parses a config text as its stage would (`None`: the defaults) and
/// returns what the instance reads and writes.
pub type LoadIo =
    fn(instance: &str, text: Option<&str>, origin: &str, dir: &Path) -> Result<Io, String>;

fn load_io<T: DeserializeOwned + Validate + Default + DeclaresTopics>(
    instance: &str,
    text: Option<&str>,
    origin: &str,
    dir: &Path,
) -> Result<Io, String> {
    let config: T = parse_or_default(text, origin).map_err(|e| e.to_string())?;
    config.topics(instance, dir)
}

/// A file of the repository (a graph, a shipped model), looked for from the
/// current folder up: the demo and the benchmark run from the repository
/// root, tests from a crate's folder.
pub fn repo_file(rel: &str) -> Result<PathBuf> {
    let cwd = std::env::current_dir()?;
    let found = cwd.ancestors().map(|a| a.join(rel)).find(|p| p.exists());
    found.ok_or_else(|| {
        anyhow::anyhow!(
            "{rel} is in neither {} nor a folder above it: run from the farsight repository",
            cwd.display()
        )
    })
}

/// When `farsight run` restarts a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Restart {
    No,
    #[default]
    OnFailure,
    Always,
}

/// A node's config: a file (relative to the graph file) or inline.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum ConfigSource {
    File(PathBuf),
    Inline(toml::Table),
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeSpec {
    pub name: String,
    pub stage: String,
    #[serde(default)]
    pub config: Option<ConfigSource>,
    #[serde(default = "robot")]
    pub machine: String,
    #[serde(default)]
    pub restart: Restart,
}

fn robot() -> String {
    "robot".into()
}

/// A topic written (`from`) or read (`to`) outside the graph: a simulator,
/// the base's driver, a laptop.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct External {
    pub topic: String,
    #[serde(default)]
    pub from: Option<String>,
    #[serde(default)]
    pub to: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraphFile {
    #[serde(default)]
    pub description: String,
    #[serde(rename = "node")]
    pub nodes: Vec<NodeSpec>,
    #[serde(default, rename = "external")]
    pub externals: Vec<External>,
}

/// A node with its config as read and what it reads and writes.
#[derive(Debug, Clone)]
pub struct Node {
    pub spec: NodeSpec,
    pub io: Io,
    /// The config's text (`None`: the stage's defaults), where it came from
    /// (for errors), and the folder its relative paths resolve against.
    pub config_text: Option<String>,
    pub config_origin: String,
    pub config_dir: PathBuf,
}

impl Node {
    /// Builds this node's stage in this process.
    pub fn build(&self) -> Result<Box<dyn farsight_stage::Stage>> {
        let entry = STAGE_KINDS
            .iter()
            .find(|e| e.kind == self.spec.stage)
            .expect("checked at load");
        let Some(build) = entry.build else {
            bail!(
                "node `{}`: a {} stage runs only as its own process, not in the in-process executor",
                self.spec.name,
                self.spec.stage
            );
        };
        build(
            &self.spec.name,
            self.config_text.as_deref(),
            &self.config_origin,
            &self.config_dir,
        )
    }
}

impl Node {
    /// The instance name, and its stage kind where that differs.
    fn label(&self, line_break: &str) -> String {
        if self.spec.name == self.spec.stage {
            self.spec.name.clone()
        } else {
            format!("{}{line_break}({})", self.spec.name, self.spec.stage)
        }
    }
}

/// A checked graph: its nodes and, per topic, who writes and who reads.
#[derive(Debug)]
pub struct Graph {
    pub path: PathBuf,
    pub description: String,
    pub nodes: Vec<Node>,
    pub topics: BTreeMap<String, TopicEdges>,
    /// Things that work but look unintended (an output nobody reads).
    pub warnings: Vec<String>,
}

#[derive(Debug, Default)]
pub struct TopicEdges {
    pub kind: Option<TopicKind>,
    /// Node names, or `external: <from>`.
    pub writers: Vec<String>,
    pub readers: Vec<(String, Need)>,
    /// The deepest queue a reader declared (the recorder's), if any: every
    /// publisher of the topic on that reader's machine also feeds it.
    pub queue_depth: Option<usize>,
    /// The nodes that read the queue.
    pub queue_readers: Vec<String>,
}

impl Graph {
    /// Reads and checks a graph file; the error names the node and topic
    /// (every problem found, one per line).
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading graph {}", path.display()))?;
        let file: GraphFile =
            toml::from_str(&text).with_context(|| format!("graph {}", path.display()))?;
        let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let mut errors = Vec::new();
        let mut nodes: Vec<Node> = Vec::new();
        for spec in file.nodes {
            if let Err(e) = topics::validate_name(&spec.name) {
                errors.push(format!(
                    "node `{}`: not a usable instance name: {}",
                    spec.name, e.why
                ));
                continue;
            }
            if nodes.iter().any(|n| n.spec.name == spec.name) {
                errors.push(format!("node `{}`: the name is used twice", spec.name));
                continue;
            }
            let Some(kind) = STAGE_KINDS.iter().find(|e| e.kind == spec.stage) else {
                let kinds: Vec<_> = STAGE_KINDS.iter().map(|e| e.kind).collect();
                errors.push(format!(
                    "node `{}`: unknown stage kind `{}` (one of {})",
                    spec.name,
                    spec.stage,
                    kinds.join(", ")
                ));
                continue;
            };
            let config = match &spec.config {
                None => Ok((None, "defaults".to_string(), dir.clone())),
                Some(ConfigSource::Inline(table)) => toml::to_string(table)
                    .map(|t| {
                        let origin = format!("{} [node.config]", path.display());
                        (Some(t), origin, dir.clone())
                    })
                    .map_err(|e| e.to_string()),
                Some(ConfigSource::File(f)) => {
                    let file = dir.join(f);
                    match std::fs::read_to_string(&file) {
                        Ok(t) => Ok((
                            Some(t),
                            file.display().to_string(),
                            file.parent().unwrap_or(Path::new(".")).to_path_buf(),
                        )),
                        Err(e) => Err(format!("cannot read config {}: {e}", file.display())),
                    }
                }
            };
            let loaded = config.and_then(|(text, origin, config_dir)| {
                let io = (kind.io)(&spec.name, text.as_deref(), &origin, &config_dir)?;
                Ok(Node {
                    spec: spec.clone(),
                    io,
                    config_text: text,
                    config_origin: origin,
                    config_dir,
                })
            });
            match loaded {
                Ok(node) => nodes.push(node),
                Err(e) => errors.push(format!("node `{}` ({}): {e}", spec.name, spec.stage)),
            }
        }

        let mut topics_map: BTreeMap<String, TopicEdges> = BTreeMap::new();
        for e in &file.externals {
            let edges = topics_map.entry(e.topic.clone()).or_default();
            match (&e.from, &e.to) {
                (Some(from), None) => edges.writers.push(format!("external: {from}")),
                (None, Some(to)) => edges
                    .readers
                    .push((format!("external: {to}"), Need::Required)),
                _ => errors.push(format!(
                    "[[external]] `{}`: give exactly one of `from` (written outside) or `to` (read outside)",
                    e.topic
                )),
            }
        }
        for n in &nodes {
            if let Err(e) = n.io.kinds() {
                errors.push(format!("node `{}`: {e}", n.spec.name));
            }
            for w in &n.io.writes {
                topics_map
                    .entry(w.clone())
                    .or_default()
                    .writers
                    .push(n.spec.name.clone());
            }
            for r in &n.io.reads {
                let edges = topics_map.entry(r.topic.clone()).or_default();
                edges.readers.push((n.spec.name.clone(), r.need));
                if let Some(d) = r.queue_depth {
                    edges.queue_depth = Some(edges.queue_depth.unwrap_or(0).max(d));
                    edges.queue_readers.push(n.spec.name.clone());
                }
            }
        }
        let mut warnings = Vec::new();
        for (topic, edges) in &mut topics_map {
            edges.kind = topics::kind_of(topic);
            if edges.kind.is_none() {
                errors.push(format!("topic `{topic}`: not a farsight topic"));
            }
            if edges.writers.len() > 1 {
                errors.push(format!(
                    "topic `{topic}`: two writers ({}); a topic has one writer (a command mux input for commands)",
                    edges.writers.join(", ")
                ));
            }
            if edges.writers.is_empty() {
                for (reader, need) in &edges.readers {
                    match need {
                        Need::Required => errors.push(format!(
                            "node `{reader}` reads `{topic}`, which nothing writes (add the node that writes it, or an [[external]] entry)"
                        )),
                        Need::Optional => warnings.push(format!(
                            "node `{reader}` reads `{topic}` (optional), which nothing writes"
                        )),
                    }
                }
            }
            if edges.readers.is_empty() && !topic.starts_with("health/") {
                warnings.push(format!(
                    "`{topic}` ({}) is read by no node",
                    edges.writers.join(", ")
                ));
            }
            // Shared memory is per machine: count the ends on each.
            let machine_of = |name: &str| {
                nodes
                    .iter()
                    .find(|n| n.spec.name == name)
                    .map(|n| n.spec.machine.clone())
            };
            let mut per_machine: BTreeMap<String, (usize, usize)> = BTreeMap::new();
            for w in &edges.writers {
                if let Some(m) = machine_of(w) {
                    per_machine.entry(m).or_default().0 += 1;
                }
            }
            for (r, _) in &edges.readers {
                if let Some(m) = machine_of(r) {
                    per_machine.entry(m).or_default().1 += 1;
                }
            }
            let mut queued_per_machine: BTreeMap<String, usize> = BTreeMap::new();
            for r in &edges.queue_readers {
                if let Some(m) = machine_of(r) {
                    *queued_per_machine.entry(m).or_default() += 1;
                }
            }
            for (machine, n) in queued_per_machine {
                // One reader, and room for its restarted self.
                if n + 1 > QUEUE_SUBSCRIBERS {
                    errors.push(format!(
                        "topic `{topic}` on {machine}: {n} queue readers ({}), a queue has room for {}",
                        edges.queue_readers.join(", "),
                        QUEUE_SUBSCRIBERS - 1
                    ));
                }
            }
            for (machine, (pubs, subs)) in per_machine {
                if pubs > MAX_PUBLISHERS {
                    errors.push(format!(
                        "topic `{topic}` on {machine}: {pubs} publishers, the transport allows {MAX_PUBLISHERS}"
                    ));
                }
                if subs > MAX_SUBSCRIBERS {
                    errors.push(format!(
                        "topic `{topic}` on {machine}: {subs} subscribers, the transport allows {MAX_SUBSCRIBERS}"
                    ));
                }
            }
        }
        if !errors.is_empty() {
            bail!(
                "graph {} has {} problem(s):\n  {}",
                path.display(),
                errors.len(),
                errors.join("\n  ")
            );
        }
        Ok(Self {
            path: path.to_path_buf(),
            description: file.description,
            nodes,
            topics: topics_map,
            warnings,
        })
    }

    /// The queues the transport keeps on `machine` (`FARSIGHT_QUEUES`,
    /// `topic=depth,...`): those whose queue readers run there. Every
    /// process of the graph on that machine gets the same declaration, so
    /// each publisher of a queued topic feeds its queue.
    pub fn queues(&self, machine: &str) -> String {
        let on_machine = |name: &String| {
            self.nodes
                .iter()
                .any(|n| n.spec.name == *name && n.spec.machine == machine)
        };
        self.topics
            .iter()
            .filter_map(|(t, e)| {
                let d = e.queue_depth?;
                e.queue_readers
                    .iter()
                    .any(on_machine)
                    .then(|| format!("{t}={d}"))
            })
            .collect::<Vec<_>>()
            .join(",")
    }

    /// The node and topic tables.
    pub fn tables(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "graph {}: {} nodes, {} topics",
            self.path.display(),
            self.nodes.len(),
            self.topics.len()
        );
        if !self.description.is_empty() {
            let _ = writeln!(out, "{}", self.description.trim());
        }
        let _ = writeln!(
            out,
            "\n{:<22} {:<18} {:<8} {:<10} {:>5} {:>6}",
            "node", "stage", "machine", "restart", "reads", "writes"
        );
        for n in &self.nodes {
            let restart = match n.spec.restart {
                Restart::No => "no",
                Restart::OnFailure => "on-failure",
                Restart::Always => "always",
            };
            let _ = writeln!(
                out,
                "{:<22} {:<18} {:<8} {:<10} {:>5} {:>6}",
                n.spec.name,
                n.spec.stage,
                n.spec.machine,
                restart,
                n.io.reads.len(),
                n.io.writes.len()
            );
        }
        let _ = writeln!(
            out,
            "\n{:<34} {:<16} {:<26} {:<7} readers (R required, O optional)",
            "topic", "kind", "writer", "queue"
        );
        for (topic, e) in &self.topics {
            let readers: Vec<String> = e
                .readers
                .iter()
                .map(|(r, need)| {
                    format!("{r} ({})", if *need == Need::Required { "R" } else { "O" })
                })
                .collect();
            let _ = writeln!(
                out,
                "{:<34} {:<16} {:<26} {:<7} {}",
                topic,
                e.kind
                    .map(|k| format!("{k:?}"))
                    .unwrap_or_else(|| "?".into()),
                e.writers.first().map(String::as_str).unwrap_or("-"),
                e.queue_depth.map_or("-".to_string(), |d| d.to_string()),
                if readers.is_empty() {
                    "-".into()
                } else {
                    readers.join(", ")
                }
            );
        }
        let base = segment_samples(MAX_SUBSCRIBERS, 1, 1);
        for (topic, e) in &self.topics {
            if let Some(d) = e.queue_depth {
                let _ = writeln!(
                    out,
                    "queue `{topic}`: depth {d} for {}; each publisher maps {} samples for it beside the topic's {base} (shared memory = samples x message size)",
                    e.queue_readers.join(", "),
                    segment_samples(QUEUE_SUBSCRIBERS, d, 1)
                );
            }
        }
        for w in &self.warnings {
            let _ = writeln!(out, "warning: {w}");
        }
        out
    }

    /// The graph as a Mermaid flowchart: nodes are stage instances, edges
    /// are topics (dashed: optional); health topics are left out; what is
    /// outside the graph is a rounded node.
    pub fn mermaid(&self) -> String {
        let mut out = String::from("flowchart LR\n");
        let id = |s: &str| s.replace(|c: char| !c.is_ascii_alphanumeric(), "_");
        for n in &self.nodes {
            let _ = writeln!(out, "  {}[\"{}\"]", id(&n.spec.name), n.label("<br/>"));
        }
        let mut outside = std::collections::BTreeSet::new();
        let mut end = |name: &str| match name.strip_prefix("external: ") {
            Some(ext) => {
                outside.insert(format!("  ext_{}([\"{ext}\"])", id(ext)));
                format!("ext_{}", id(ext))
            }
            None => id(name),
        };
        let mut edges = String::new();
        for (topic, e) in self.shown_topics() {
            for w in &e.writers {
                let from = end(w);
                for (r, need) in &e.readers {
                    let arrow = if *need == Need::Required {
                        "-->"
                    } else {
                        "-.->"
                    };
                    let _ = writeln!(edges, "  {from} {arrow}|{topic}| {}", end(r));
                }
            }
        }
        for o in outside {
            let _ = writeln!(out, "{o}");
        }
        out + &edges
    }

    /// The graph in Graphviz DOT, as [`Graph::mermaid`].
    pub fn dot(&self) -> String {
        let mut out = String::from("digraph farsight {\n  rankdir=LR;\n  node [shape=box];\n");
        for n in &self.nodes {
            let _ = writeln!(out, "  \"{}\" [label=\"{}\"];", n.spec.name, n.label("\\n"));
        }
        let mut outside = std::collections::BTreeSet::new();
        let mut end = |name: &str| match name.strip_prefix("external: ") {
            Some(ext) => {
                outside.insert(format!("  \"{ext}\" [shape=ellipse];"));
                ext.to_string()
            }
            None => name.to_string(),
        };
        let mut edges = String::new();
        for (topic, e) in self.shown_topics() {
            for w in &e.writers {
                let from = end(w);
                for (r, need) in &e.readers {
                    let style = if *need == Need::Required {
                        "solid"
                    } else {
                        "dashed"
                    };
                    let to = end(r);
                    let _ = writeln!(
                        edges,
                        "  \"{from}\" -> \"{to}\" [label=\"{topic}\", style={style}];"
                    );
                }
            }
        }
        for o in outside {
            let _ = writeln!(out, "{o}");
        }
        out + &edges + "}\n"
    }

    fn shown_topics(&self) -> impl Iterator<Item = (&String, &TopicEdges)> {
        self.topics
            .iter()
            .filter(|(t, _)| !t.starts_with("health/"))
    }
}

#[derive(Debug, clap::Subcommand)]
pub enum GraphCommand {
    /// Load every node's config, compute the edges, and fail naming node and
    /// topic for what would not run; prints the node and topic tables.
    Check {
        /// A graph file (graphs/*.toml).
        graph: PathBuf,
        /// Also write the graph as a Mermaid flowchart.
        #[arg(long)]
        mermaid: Option<PathBuf>,
        /// Also write the graph in Graphviz DOT.
        #[arg(long)]
        dot: Option<PathBuf>,
    },
}

pub fn run(c: GraphCommand) -> Result<()> {
    match c {
        GraphCommand::Check {
            graph,
            mermaid,
            dot,
        } => {
            let g = Graph::load(&graph)?;
            print!("{}", g.tables());
            for (path, text) in [(mermaid, g.mermaid()), (dot, g.dot())] {
                if let Some(p) = path {
                    std::fs::write(&p, text).with_context(|| format!("writing {}", p.display()))?;
                    println!("wrote {}", p.display());
                }
            }
            println!("ok");
            Ok(())
        }
    }
}
