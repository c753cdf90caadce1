//! `farsight`: the command-line tool of the farsight stack.
//!
//! ```text
//! farsight probe publish   --width 1440 --height 1080 --rate-hz 30   # test frames into shared memory
//! farsight probe subscribe --frames 90                              # receive and check every byte
//! farsight bench transport                                           # iceoryx2 vs zenoh vs Unix socket
//! farsight demo                                                      # closed loop in the simulator (bug-trap); --orfd: real frames
//! farsight infer --model-config deploy/models/twinlitenet.toml IMAGES --out out/infer
//! farsight hip-library poses.csv --k 200 --out hip-library.toml      # HIP trajectory library
//! farsight record --topics 'camera/**' --out run.mcap               # record; --info FILE summarises
//! farsight replay run.mcap --speed 4                                # or --lockstep --driving T --answer T
//! farsight diff golden.mcap run.mcap                                # field-by-field comparison
//! farsight dataset run.mcap --out data/train                        # LRN + FITAM labels from a recording
//! farsight foxglove                                                # live view for the Foxglove app (ws://127.0.0.1:8765)
//! farsight inspect --connect tcp/ROBOT:7447 --robot NAME            # the graph from a laptop
//! farsight graph check graphs/robot.toml --mermaid robot.mmd         # nodes, topics, what would not run
//! farsight run graphs/orfd.toml --out run                           # start and supervise a graph's nodes
//! ```

mod bench;
mod bench_e2e;
mod bench_fitam;
mod bench_inference;
mod bench_nav;
mod bench_navigation;
mod bench_planning;
mod bench_record;
mod bench_recorder;
mod chaos;
mod dataset;
mod demo;
mod demo_sim;
mod fitam_rig;
mod foxglove;
mod graph;
mod hip_library;
mod infer;
mod inspect;
mod jobs;
mod lockstep;
mod memory;
mod probe;
mod recording;
mod run;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "farsight",
    version,
    about = "farsight: long-range visual navigation, command-line tools"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check the transport on this machine with test frames whose every byte is verified.
    #[command(subcommand)]
    Probe(probe::ProbeCommand),
    /// Benchmarks that print a table.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// The closed loop in simulation (default: bug-trap), or with --orfd the graph on the real ORFD frames.
    Demo(demo::DemoArgs),
    /// Motion safety under faults: the simulator drives the FITAM graph in real
    /// time while stages are killed and frozen at random; prints stale moving
    /// commands, self-exits, restart-to-output and distance made good.
    Chaos(chaos::ChaosArgs),
    /// Self-supervised training sets (LRN hotspots, FITAM far-field classes) from recordings.
    Dataset(dataset::DatasetArgs),
    /// Run a model on image files offline, as the inference stage would, and write PNGs.
    Infer(infer::InferArgs),
    /// Build HIP's trajectory library (k-means of recorded futures) from poses.
    HipLibrary(hip_library::HipLibraryArgs),
    /// Record topics into an MCAP file (or --info FILE: what a recording holds).
    Record(recording::RecordArgs),
    /// Replay a recording into the graph: recorded pace, a factor, or lock-step.
    Replay(recording::ReplayArgs),
    /// Compare a run's recording against a golden one, field by field.
    Diff(recording::DiffArgs),
    /// The robot's graph from a laptop over zenoh: stages, health, rates, latency; echo; snapshot PNGs.
    Inspect(inspect::InspectArgs),
    /// Watch the graph live in the Foxglove app: a read-only Foxglove WebSocket
    /// server fed from shared memory or, with --connect, a robot's bridge.
    Foxglove(foxglove::FoxgloveArgs),
    /// Graph files (graphs/*.toml): check one, draw it as Mermaid or DOT.
    #[command(subcommand)]
    Graph(graph::GraphCommand),
    /// Start this machine's nodes of a graph file and supervise them as
    /// systemd would (notify, watchdog, restart with back-off); Ctrl-C stops.
    Run(run::RunArgs),
}

fn main() {
    let cli = Cli::parse();
    match &cli.command {
        // The benchmark runs whole graphs in this process: their stages'
        // health changes are not news there (RUST_LOG still says otherwise).
        Command::Bench(_) => {
            farsight_stage::init_tracing_with(farsight_stage::LogFormat::Text, "error")
        }
        _ => farsight_stage::init_tracing(farsight_stage::LogFormat::Text),
    }
    let result = match cli.command {
        Command::Probe(c) => probe::run(c),
        Command::Bench(c) => bench::run(c),
        Command::Demo(a) => demo::run(a),
        Command::Chaos(a) => chaos::main(a),
        Command::Infer(a) => infer::run(a),
        Command::Dataset(a) => dataset::run(a),
        Command::HipLibrary(a) => hip_library::run(a),
        Command::Record(a) => recording::run_record(a),
        Command::Replay(a) => recording::run_replay(a),
        Command::Diff(a) => recording::run_diff(a),
        Command::Inspect(a) => inspect::run(a),
        Command::Foxglove(a) => foxglove::run(a),
        Command::Graph(c) => graph::run(c),
        Command::Run(a) => run::run(a),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// How a laptop-side command logs in to a robot's zenoh router: `--user`
/// with the password in `FARSIGHT_ZENOH_PASSWORD` (never on the command
/// line, where `ps` shows it), or no credentials.
#[derive(Debug, Clone, clap::Args)]
pub struct Login {
    /// User name for the robot's router (deploy/zenoh/users.txt); the
    /// password comes from FARSIGHT_ZENOH_PASSWORD.
    #[arg(long, global = true)]
    pub user: Option<String>,
}

impl Login {
    /// A zenoh client config for `connect`, with the credentials if given.
    pub fn client_config(&self, mode: &str, connect: &[String]) -> anyhow::Result<zenoh::Config> {
        use farsight_interfaces::transport::net::NetBus;
        let config = NetBus::config(mode, &[], connect)?;
        let Some(user) = &self.user else {
            return Ok(config);
        };
        let password = std::env::var("FARSIGHT_ZENOH_PASSWORD").map_err(|_| {
            anyhow::anyhow!("--user {user}: set FARSIGHT_ZENOH_PASSWORD to the password")
        })?;
        Ok(NetBus::with_credentials(config, user, &password)?)
    }
}
