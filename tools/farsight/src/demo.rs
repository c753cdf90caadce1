//! `farsight demo --orfd`: runs the graph file `graphs/orfd.toml` as
//! separate processes (under `farsight run`) on the real ORFD off-road
//! frames and watches it the way a laptop would. (Without `--orfd`, the demo
//! is the closed loop in simulation: [`crate::demo_sim`].)
//!
//! camera-ingest (folder of real frames) -> inference (TwinLiteNet) ->
//! subgoal-selection (POVNav) -> velocity-servoing, all in iceoryx2 shared
//! memory, with this process playing the robot (pose, and a goal 200 m ahead)
//! and, through the graph's bridge and zenoh, the laptop: it saves every
//! frame (JPEG, as the bridge sends it to fit a 10 Mbit/s link) and
//! navigability image (PNG) it receives and reports the commands.
//! `--frames`, `--rate-hz` and `--loops` other than the graph's run a copy of
//! the graph with those values, written to the output folder; `--loops 0`
//! plays until Ctrl-C (or SIGTERM), then writes the summary as a finished
//! run does. `--foxglove-port` serves the run to the Foxglove app the way a
//! laptop does: `farsight foxglove --connect` on the graph's bridge.

use anyhow::{bail, Context, Result};
use clap::Args;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{
    CommandReason, GoalKind, HealthState, NavGoal, PixelEncoding, Pose,
};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, IpcSettings};
use farsight_interfaces::transport::net::NetBus;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

#[derive(Args)]
pub struct DemoArgs {
    /// Output folder (configs, logs, map PNG, summary).
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Simulator scenario to drive (see farsight-sim's scenario list).
    #[arg(long, default_value = "bug-trap")]
    scenario: String,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// How the graph navigates in simulation.
    #[arg(long, value_enum, default_value = "fitam")]
    method: crate::demo_sim::Method,
    /// Named mode: the simulator's class image stands in for the inference stage.
    #[arg(long)]
    oracle: bool,
    /// Drive this graph file instead of --method's (any graphs/sim/*.toml,
    /// or your own): the simulator provides what its [[external]] topics
    /// ask for.
    #[arg(long)]
    graph: Option<PathBuf>,
    /// Simulated seconds before the run counts as failed.
    #[arg(long, default_value_t = 240.0)]
    max_time_s: f64,
    /// The simulator on the wall clock, 10 frames a second, taking whatever
    /// command is newest (as a robot does), instead of lock-step.
    #[arg(long)]
    realtime: bool,
    /// Lock-step: seconds the simulator waits for the graph's command
    /// before driving a frame without it (counted in summary.toml as a late
    /// command). Only a graph that stopped answering should reach it; raise
    /// it on a machine so loaded that a stage can be starved this long.
    #[arg(long, default_value_t = 10.0, value_parser = farsight_sim::run::parse_timeout_s)]
    command_timeout_s: f64,
    /// How many messages of each topic the recorder may fall behind before
    /// it loses one (its queues); 0 reads each topic's latest value.
    #[arg(long, default_value_t = 8)]
    recorder_queue_depth: usize,
    /// Instead of the simulator: the real ORFD frames through TwinLiteNet and
    /// POVNav (graphs/orfd.toml).
    #[arg(long)]
    orfd: bool,
    /// Folder of frames to play [default: graphs/orfd.toml's,
    /// ../shared/data/orfd/image_data from the repository root].
    #[arg(long)]
    frames: Option<PathBuf>,
    /// Passes over the folder, 0: until Ctrl-C [default: graphs/orfd.toml's].
    #[arg(long)]
    loops: Option<u32>,
    /// Frames per second [default: graphs/orfd.toml's].
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Serve the run live to the Foxglove app (`farsight foxglove`) on
    /// ws://127.0.0.1:PORT: in simulation from shared memory; with --orfd
    /// from the graph's bridge over zenoh, as a laptop watches a robot.
    #[arg(long, value_name = "PORT")]
    foxglove_port: Option<u16>,
}

pub struct Stage(pub(crate) Child);

impl Drop for Stage {
    fn drop(&mut self) {
        // SIGTERM first so the stage publishes its last health and cleans up.
        let _ = Command::new("kill")
            .arg("-TERM")
            .arg(self.0.id().to_string())
            .status();
        let end = Instant::now() + Duration::from_secs(3);
        while Instant::now() < end {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub(crate) fn sibling(name: &str) -> Result<PathBuf> {
    let p = std::env::current_exe()?.with_file_name(name);
    if !p.exists() {
        bail!(
            "{} not found: build the workspace first (cargo xtask demo does)",
            p.display()
        );
    }
    Ok(p)
}

/// Has the child get SIGTERM when this process dies, however it dies
/// (SIGKILL included): a demo or chaos run that is killed leaves no stages
/// behind to eat the machine.
pub(crate) fn die_with_parent(cmd: &mut Command) -> &mut Command {
    use std::os::unix::process::CommandExt;
    // SAFETY: prctl is async-signal-safe and touches no memory of the
    // parent; it runs in the forked child before exec.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        })
    }
}

pub fn run(a: DemoArgs) -> Result<()> {
    if !a.orfd {
        return crate::demo_sim::run(crate::demo_sim::SimDemo {
            out: a.out,
            scenario: a.scenario,
            seed: a.seed,
            method: a.method,
            oracle: a.oracle,
            graph: a.graph,
            max_time_s: a.max_time_s,
            realtime: a.realtime,
            command_timeout_s: a.command_timeout_s,
            recorder_queue_depth: a.recorder_queue_depth,
            foxglove_port: a.foxglove_port,
        });
    }
    let out = a.out.clone();
    std::fs::create_dir_all(out.join("frames"))?;
    let out = std::fs::canonicalize(&out)?;
    let orfd = OrfdGraph::prepare(&a, &out)?;
    let frames = orfd.frames.clone();
    // Its own shared-memory namespace, or the caller's (`farsight bench
    // e2e` taps the graph from outside).
    let prefix = std::env::var("FARSIGHT_IPC_PREFIX")
        .unwrap_or_else(|_| format!("demo{}_", std::process::id()));

    println!("farsight demo: camera-ingest -> inference -> subgoal-selection -> velocity-servoing, watched over zenoh");
    println!("  graph: {}", orfd.path.display());
    println!("  frames: {}", frames.display());
    println!("  output: {}", out.display());
    // The robot side: pose at the origin facing east, a goal 200 m ahead,
    // there (history) for the stages when they subscribe.
    let robot = Bus::open_with(
        "demo-robot",
        // FARSIGHT_IPC_ROOT as the graph's nodes inherit it: with another
        // root they would never see this pose and goal.
        &IpcSettings {
            prefix: Some(prefix.clone()),
            queues: Some(orfd.queues.clone()),
            ..IpcSettings::from_env()
        },
    )?;
    let pose_pub = robot.publisher(&topics::pose())?;
    let goal_pub = robot.publisher(&topics::goal())?;
    goal_pub.publish(&NavGoal {
        kind: GoalKind::LOCAL,
        x_m: 200.0,
        tolerance_m: 2.0,
        ..Default::default()
    })?;
    // The laptop side, subscribed before the graph starts (every node at
    // once, camera-ingest's first frame among them): it connects to the
    // bridge as soon as the bridge listens, trying every 100 ms.
    let mut zenoh = NetBus::config("peer", &[], std::slice::from_ref(&orfd.endpoint))?;
    zenoh
        .insert_json5(
            "connect/retry",
            "{ period_init_ms: 100, period_max_ms: 100, period_increase_factor: 1.0 }",
        )
        .map_err(|e| anyhow::anyhow!("zenoh connect/retry: {e}"))?;
    let net = NetBus::open(zenoh, "demo")?;
    let mut images = net.slice_subscriber(&topics::camera_image("front"))?;
    let mut health = net.subscriber(&topics::health("camera-ingest"))?;
    let mut info = net.subscriber(&topics::camera_info("front"))?;
    let mut nav_images = net.slice_subscriber(&topics::navigability("front"))?;
    let mut commands = net.subscriber(&topics::velocity_command())?;
    let mut subgoals = net.subscriber(&topics::subgoal())?;
    // Every node of the graph, each one's config and log in `out`.
    let stages = crate::run::start_graph(&orfd.path, &out, &prefix, "", Duration::from_secs(120))?;
    // The laptop's Foxglove server, once the bridge listens: a zenoh
    // client gives up at once on an endpoint nobody listens on.
    let foxglove = a
        .foxglove_port
        .map(|port| {
            crate::demo_sim::start_foxglove(
                &out,
                &prefix,
                port,
                Some((&orfd.endpoint, &orfd.robot)),
            )
        })
        .transpose()?;
    std::fs::create_dir_all(out.join("navigability"))?;
    let started = Instant::now();
    let (mut tracking, mut v_sum, mut w_abs_max, mut last_subgoal) = (0u64, 0.0f64, 0.0f64, None);

    // None: `--loops 0`, until Ctrl-C.
    let expected = (orfd.loops > 0)
        .then(|| -> Result<u64> {
            Ok(orfd.loops as u64 * std::fs::read_dir(&frames)?.count() as u64)
        })
        .transpose()?;
    let (mut received, mut bytes, mut last_health, mut camera) = (0u64, 0usize, None, None);
    // What the bridge sent the frames as (the graph's export config).
    let mut frame_encoding = PixelEncoding::JPEG;
    // A stall, not a length: the run ends when no frame came for this long.
    const STALL: Duration = Duration::from_secs(60);
    let mut last_frame = Instant::now();
    let mut stopped = false;
    while expected.is_none_or(|n| received < n) && last_frame.elapsed() < STALL {
        if robot.termination_requested() {
            stopped = true;
            break;
        }
        // Stamped now, as a localisation stack would: the stages judge
        // the pose's age on its capture time.
        pose_pub.publish(&Pose {
            stamp: farsight_interfaces::msg::Stamp::new(0, WallClock.now_ns()),
            ..Default::default()
        })?;
        goal_pub.deliver_history()?;
        // The laptop samples the newest command (zenoh keeps only the latest).
        if let Some(c) = commands.latest()? {
            if c.reason == CommandReason::TRACKING {
                tracking += 1;
                v_sum += c.linear_mps as f64;
                w_abs_max = w_abs_max.max(c.angular_radps.abs() as f64);
            }
        }
        if let Some(s) = subgoals.latest()? {
            last_subgoal = Some(s);
        }
        if let Some((h, data)) = nav_images.latest()? {
            std::fs::write(
                out.join("navigability")
                    .join(format!("{:04}.png", h.stamp.frame_seq)),
                &data,
            )?;
        }
        if let Some(h) = health.latest()? {
            last_health = Some(h);
        }
        if let Some(i) = info.latest()? {
            camera = Some(i);
        }
        let Some((h, data)) = images.recv_timeout(Duration::from_millis(200))? else {
            if last_health.is_some_and(|h: farsight_interfaces::msg::StageHealth| {
                h.state == HealthState::STOPPING
            }) {
                break;
            }
            continue;
        };
        let extension = match h.encoding {
            PixelEncoding::JPEG => "jpg",
            PixelEncoding::PNG => "png",
            other => bail!("expected JPEG or PNG frames from the bridge, got {other}"),
        };
        frame_encoding = h.encoding;
        received += 1;
        last_frame = Instant::now();
        bytes += data.len();
        let name = out
            .join("frames")
            .join(format!("{:04}.{extension}", h.stamp.frame_seq));
        std::fs::write(&name, &data)?;
        print!(
            "\r  frame {:>3}/{}  {}x{} {extension} {:>4} kB  capture {} ms",
            h.stamp.frame_seq,
            expected.map_or("-".to_string(), |n| n.to_string()),
            h.width,
            h.height,
            data.len() / 1024,
            h.stamp.capture_time_ns / 1_000_000
        );
        std::io::stdout().flush().ok();
    }
    println!();
    let elapsed = started.elapsed().as_secs_f64();
    // Its closing report (per Foxglove topic: messages, MB) on stdout,
    // under the progress line.
    drop(foxglove);
    // camera-ingest ends when it has played its loops: its last health
    // report (stopping) carries the final counts.
    let end = Instant::now() + Duration::from_secs(2);
    while Instant::now() < end
        && !last_health.is_some_and(|h: farsight_interfaces::msg::StageHealth| {
            h.state == HealthState::STOPPING
        })
    {
        if let Some(h) = health.latest()? {
            last_health = Some(h);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    drop(stages);

    let mut summary = String::new();
    let of = match expected {
        Some(n) => format!("{n}"),
        None => "endless (--loops 0)".into(),
    };
    summary += &format!(
        "received {received} of {of} frames over zenoh in {elapsed:.1} s ({:.1} frames/s){}\n",
        received as f64 / elapsed,
        if stopped { ", stopped by a signal" } else { "" }
    );
    summary += &format!(
        "mean {} size {} kB (frames downsampled 2x by the bridge), {:.1} kB/s of camera frames over zenoh\n",
        frame_encoding.to_string().to_uppercase(),
        bytes / received.max(1) as usize / 1024,
        bytes as f64 / elapsed / 1e3
    );
    if let Some(c) = camera {
        summary += &format!(
            "camera '{}' {}x{} fx {:.2} fy {:.2} cx {:.2} cy {:.2}\n",
            c.name, c.width, c.height, c.fx, c.fy, c.cx, c.cy
        );
    }
    if let Some(h) = last_health {
        summary += &format!(
            "camera-ingest health: {} in={} out={} dropped={}\n",
            h.state, h.messages_in, h.messages_out, h.dropped
        );
    }
    if tracking > 0 {
        summary += &format!(
            "velocity commands sampled while tracking: {tracking}, mean v {:.2} m/s, max |omega| {:.2} rad/s\n",
            v_sum / tracking as f64,
            w_abs_max
        );
    } else {
        summary += "no tracking velocity command was received (see velocity-servoing.log)\n";
    }
    if let Some(s) = last_subgoal {
        summary += &format!(
            "last POVNav subgoal: HOG ({:.0}, {:.0}) px, proximity {:.0} px, alignment {:.2} rad, mode {}\n",
            s.image_u_px, s.image_v_px, s.proximity_lambda_px, s.alignment_phi_rad, s.mode
        );
    }
    summary += &format!(
        "frames written to {}, navigability to {}\n",
        out.join("frames").display(),
        out.join("navigability").display()
    );
    std::fs::write(out.join("summary.txt"), &summary)?;
    println!("\n{summary}");
    if received == 0 {
        bail!("no frames arrived; logs are in {}", out.display());
    }
    Ok(())
}

/// The ORFD demo's graph, relative to the repository root.
const ORFD_GRAPH: &str = "graphs/orfd.toml";

/// Config keys whose values are paths, relative ones resolving against the
/// graph file's folder (camera-ingest, inference, costmap-fusion,
/// subgoal-selection, bridge).
const PATH_KEYS: [&str; 9] = [
    "folder",
    "depth_folder",
    "file",
    "camera_info",
    "model_config",
    "class_table",
    "hip_library",
    "hip_model",
    "config_file",
];

/// The graph the ORFD demo runs and what the demo needs to know of it.
struct OrfdGraph {
    /// `graphs/orfd.toml`, or the copy with the user's values in `out`.
    path: PathBuf,
    /// camera-ingest's frames folder and passes over it.
    frames: PathBuf,
    loops: u32,
    /// Where the graph's bridge listens (the laptop side connects there).
    endpoint: String,
    /// The bridge's robot name (the `<robot>` of its zenoh keys).
    robot: String,
    /// The queues the graph declares (its recorder's): this process
    /// publishes the pose and goal, so it feeds them too.
    queues: String,
}

impl OrfdGraph {
    /// Loads `graphs/orfd.toml`; with `--frames`, `--rate-hz` or `--loops`
    /// other than its values, writes a copy with them (relative paths made
    /// absolute) to `out/orfd.toml` and runs that.
    fn prepare(a: &DemoArgs, out: &Path) -> Result<Self> {
        let path = std::path::absolute(crate::graph::repo_file(ORFD_GRAPH)?)?;
        let dir = path.parent().unwrap_or(Path::new("/")).to_path_buf();
        let graph = crate::graph::Graph::load(&path)?;
        let node = |stage: &str| {
            graph
                .nodes
                .iter()
                .find(|n| n.spec.stage == stage)
                .with_context(|| format!("{}: no {stage} node", path.display()))
        };
        let ingest_node = node("camera-ingest")?;
        let ingest: farsight_camera_ingest::IngestConfig = match &ingest_node.config_text {
            Some(t) => farsight_stage::parse_config(t, &ingest_node.config_origin)?,
            None => Default::default(),
        };
        let [camera] = ingest.cameras.as_slice() else {
            bail!(
                "{}: the demo plays one camera's frames; node `{}` has {}",
                path.display(),
                ingest_node.spec.name,
                ingest.cameras.len()
            );
        };
        let bridge_node = node("bridge")?;
        let bridge: farsight_bridge::BridgeConfig = match &bridge_node.config_text {
            Some(t) => farsight_stage::parse_config(t, &bridge_node.config_origin)?,
            None => Default::default(),
        };
        let endpoint = bridge.zenoh.listen.first().cloned().with_context(|| {
            format!(
                "{}: node `{}` listens nowhere (zenoh.listen): the demo connects there",
                path.display(),
                bridge_node.spec.name
            )
        })?;
        // A clear word for a port in use (another demo, a bridge): the
        // graph's bridge would fail to start.
        if let Some(addr) = endpoint.strip_prefix("tcp/") {
            if let Err(e) = std::net::TcpListener::bind(addr) {
                bail!(
                    "{endpoint} (where {}'s bridge listens) is not free: {e}",
                    path.display()
                );
            }
        }

        let graph_frames = ingest_node.config_dir.join(&camera.folder);
        let mut set: Vec<(&str, toml::Value)> = Vec::new();
        let frames = match &a.frames {
            Some(f) => {
                let f = std::fs::canonicalize(f).with_context(|| {
                    format!(
                        "frames folder {} (run from the repository root, next to ../shared)",
                        f.display()
                    )
                })?;
                if std::fs::canonicalize(&graph_frames).ok().as_ref() != Some(&f) {
                    set.push(("folder", f.display().to_string().into()));
                }
                f
            }
            None => std::fs::canonicalize(&graph_frames).with_context(|| {
                format!(
                    "frames folder {} ({}'s; ORFD's frames belong in ../shared/data/orfd next to the repository, or pass --frames)",
                    graph_frames.display(),
                    path.display()
                )
            })?,
        };
        let rate_hz = a.rate_hz.unwrap_or(camera.rate_hz);
        if rate_hz != camera.rate_hz {
            set.push(("rate_hz", rate_hz.into()));
        }
        let loops = a.loops.unwrap_or(camera.loops);
        if loops != camera.loops {
            set.push(("loops", i64::from(loops).into()));
        }
        if set.is_empty() {
            return Ok(Self {
                path,
                frames,
                loops,
                endpoint,
                robot: bridge.robot.clone(),
                queues: graph.queues("robot"),
            });
        }

        // The copy: the graph's TOML with the user's values in the camera
        // table, edited as data and written by the serializer.
        let text = std::fs::read_to_string(&path)?;
        let mut doc: toml::Table =
            toml::from_str(&text).with_context(|| format!("graph {}", path.display()))?;
        let nodes = doc
            .get_mut("node")
            .and_then(toml::Value::as_array_mut)
            .context("a graph has [[node]] tables")?;
        for n in nodes.iter_mut() {
            let n = n.as_table_mut().context("[[node]] is a table")?;
            // The copy lives in `out`: every relative path is made absolute.
            match n.get_mut("config") {
                Some(toml::Value::String(file)) => *file = absolute(&dir.join(&*file))?,
                Some(config) => absolutize(config, None, &dir)?,
                None => {}
            }
            if n.get("name").and_then(toml::Value::as_str) != Some(&ingest_node.spec.name) {
                continue;
            }
            let camera = n
                .get_mut("config")
                .and_then(toml::Value::as_table_mut)
                .and_then(|c| c.get_mut("cameras"))
                .and_then(toml::Value::as_array_mut)
                .and_then(|c| c.first_mut())
                .and_then(toml::Value::as_table_mut)
                .with_context(|| {
                    format!(
                        "{}: node `{}`'s [[node.config.cameras]] is not inline",
                        path.display(),
                        ingest_node.spec.name
                    )
                })?;
            for (key, value) in &set {
                camera.insert(key.to_string(), value.clone());
            }
        }
        let copy = out.join("orfd.toml");
        let changed: Vec<String> = set.iter().map(|(k, v)| format!("{k} = {v}")).collect();
        std::fs::write(
            &copy,
            format!(
                "# {} with the demo's {} (written by farsight demo --orfd)\n{}",
                path.display(),
                changed.join(", "),
                toml::to_string(&doc)?
            ),
        )
        .with_context(|| format!("writing {}", copy.display()))?;
        Ok(Self {
            path: copy,
            frames,
            loops,
            endpoint,
            robot: bridge.robot.clone(),
            queues: graph.queues("robot"),
        })
    }
}

/// Makes the relative paths (the values of [`PATH_KEYS`]) in a node's
/// inline config absolute against `dir`.
fn absolutize(value: &mut toml::Value, key: Option<&str>, dir: &Path) -> Result<()> {
    match value {
        toml::Value::String(s) if key.is_some_and(|k| PATH_KEYS.contains(&k)) && !s.is_empty() => {
            *s = absolute(&dir.join(&*s))?;
        }
        toml::Value::Array(items) => {
            for item in items {
                absolutize(item, key, dir)?;
            }
        }
        toml::Value::Table(table) => {
            for (k, v) in table.iter_mut() {
                absolutize(v, Some(k), dir)?;
            }
        }
        _ => {}
    }
    Ok(())
}

/// `path` made absolute, without `..` where it exists.
fn absolute(path: &Path) -> Result<String> {
    let p = std::fs::canonicalize(path).or_else(|_| std::path::absolute(path))?;
    Ok(p.display().to_string())
}
