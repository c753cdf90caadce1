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
use farsight_interfaces::transport::ipc::{MAX_PUBLISHERS, MAX_SUBSCRIBERS};
use farsight_stage::{DeclaresTopics, Io, Need, Validate};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Every stage kind a graph node may name, with the function that loads
/// its config and says what it reads and writes.
pub const STAGE_KINDS: [(&str, LoadIo); 8] = [
    (
        "camera-ingest",
        load_io::<farsight_camera_ingest::IngestConfig>,
    ),
    (
        "inference",
        load_io::<farsight_inference::stage::InferenceConfig>,
    ),
    (
        "bin-projection",
        load_io::<farsight_bin_projection::stage::BinProjectionConfig>,
    ),
    (
        "costmap-fusion",
        load_io::<farsight_costmap_fusion::stage::FusionStageConfig>,
    ),
    (
        "subgoal-selection",
        load_io::<farsight_subgoal_selection::stage::SubgoalStageConfig>,
    ),
    (
        "velocity-servoing",
        load_io::<farsight_velocity_servoing::stage::ServoStageConfig>,
    ),
    ("command-mux", load_io::<farsight_command_mux::MuxConfig>),
    ("bridge", load_io::<farsight_bridge::BridgeConfig>),
];

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
    let config: T = match text {
        Some(t) => farsight_stage::parse_config(t, origin).map_err(|e| e.to_string())?,
        None => {
            let c = T::default();
            c.validate().map_err(|e| e.to_string())?;
            c
        }
    };
    config.topics(instance, dir)
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

/// A node with what it reads and writes.
#[derive(Debug, Clone)]
pub struct Node {
    pub spec: NodeSpec,
    pub io: Io,
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
            let Some((_, load)) = STAGE_KINDS.iter().find(|(k, _)| *k == spec.stage) else {
                let kinds: Vec<_> = STAGE_KINDS.iter().map(|(k, _)| *k).collect();
                errors.push(format!(
                    "node `{}`: unknown stage kind `{}` (one of {})",
                    spec.name,
                    spec.stage,
                    kinds.join(", ")
                ));
                continue;
            };
            let loaded = match &spec.config {
                None => load(&spec.name, None, "defaults", &dir),
                Some(ConfigSource::Inline(table)) => match toml::to_string(table) {
                    Ok(t) => load(
                        &spec.name,
                        Some(&t),
                        &format!("{} [node.config]", path.display()),
                        &dir,
                    ),
                    Err(e) => Err(e.to_string()),
                },
                Some(ConfigSource::File(f)) => {
                    let file = dir.join(f);
                    match std::fs::read_to_string(&file) {
                        Ok(t) => load(
                            &spec.name,
                            Some(&t),
                            &file.display().to_string(),
                            file.parent().unwrap_or(Path::new(".")),
                        ),
                        Err(e) => Err(format!("cannot read config {}: {e}", file.display())),
                    }
                }
            };
            match loaded {
                Ok(io) => nodes.push(Node { spec, io }),
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
                topics_map
                    .entry(r.topic.clone())
                    .or_default()
                    .readers
                    .push((n.spec.name.clone(), r.need));
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
            "\n{:<34} {:<16} {:<26} readers (R required, O optional)",
            "topic", "kind", "writer"
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
                "{:<34} {:<16} {:<26} {}",
                topic,
                e.kind
                    .map(|k| format!("{k:?}"))
                    .unwrap_or_else(|| "?".into()),
                e.writers.first().map(String::as_str).unwrap_or("-"),
                if readers.is_empty() {
                    "-".into()
                } else {
                    readers.join(", ")
                }
            );
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
