//! `farsight demo --orfd`: runs the graph as separate processes on the real
//! ORFD off-road frames and watches it the way a laptop would. (Without
//! `--orfd`, the demo is the closed loop in simulation: [`crate::demo_sim`].)
//!
//! camera-ingest (folder of real frames) -> inference (TwinLiteNet) ->
//! subgoal-selection (POVNav) -> velocity-servoing, all in iceoryx2 shared
//! memory, with this process playing the robot (pose, and a goal 200 m ahead)
//! and, through the bridge and zenoh, the laptop: it saves every frame and
//! navigability image it receives as PNG and reports the commands.

use anyhow::{bail, Context, Result};
use clap::Args;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{
    CommandReason, GoalKind, HealthState, NavGoal, PixelEncoding, Pose,
};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, IpcSettings};
use farsight_interfaces::transport::net::NetBus;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
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
    /// Simulated seconds before the run counts as failed.
    #[arg(long, default_value_t = 240.0)]
    max_time_s: f64,
    /// Instead of the simulator: the real ORFD frames through TwinLiteNet and POVNav.
    #[arg(long)]
    orfd: bool,
    /// Folder of frames to play.
    #[arg(long, default_value = "../shared/data/orfd/image_data")]
    frames: PathBuf,
    /// Passes over the folder.
    #[arg(long, default_value_t = 3)]
    loops: u32,
    /// Frames per second.
    #[arg(long, default_value_t = 10.0)]
    rate_hz: f64,
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

/// Starts a stage and waits for its `<name> ready` line.
pub fn start_ready(name: &'static str, config: &Path, prefix: &str, out: &Path) -> Result<Stage> {
    let log = out.join(format!("{name}.log"));
    let mut stage = start(name, config, prefix, &log)?;
    let mut ready = String::new();
    BufReader::new(stage.0.stdout.take().expect("stdout")).read_line(&mut ready)?;
    if ready.trim() != format!("{name} ready") {
        bail!("farsight-{name} did not start; see {}", log.display());
    }
    Ok(stage)
}

fn start(name: &'static str, config: &Path, prefix: &str, log: &Path) -> Result<Stage> {
    start_logging(name, config, prefix, std::fs::File::create(log)?)
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

/// Starts a stage with its stderr into `log_file` (a restarted stage's log
/// goes on in the same file); its stdout stays piped for the ready line.
pub(crate) fn start_logging(
    name: &'static str,
    config: &Path,
    prefix: &str,
    log_file: std::fs::File,
) -> Result<Stage> {
    let child = die_with_parent(&mut Command::new(sibling(&format!("farsight-{name}"))?))
        .arg("--config")
        .arg(config)
        .env("FARSIGHT_IPC_PREFIX", prefix)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(log_file)
        .spawn()
        .with_context(|| format!("starting farsight-{name}"))?;
    Ok(Stage(child))
}

pub fn run(a: DemoArgs) -> Result<()> {
    if !a.orfd {
        return crate::demo_sim::run(crate::demo_sim::SimDemo {
            out: a.out,
            scenario: a.scenario,
            seed: a.seed,
            method: a.method,
            oracle: a.oracle,
            max_time_s: a.max_time_s,
        });
    }
    let frames = std::fs::canonicalize(&a.frames).with_context(|| {
        format!(
            "frames folder {} (run from the repository root, next to ../shared)",
            a.frames.display()
        )
    })?;
    let out = a.out.clone();
    std::fs::create_dir_all(out.join("frames"))?;
    let out = std::fs::canonicalize(&out)?;
    let prefix = format!("demo{}_", std::process::id());
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");

    let ingest_cfg = out.join("camera-ingest.toml");
    std::fs::write(
        &ingest_cfg,
        format!(
            "# ORFD camera (calib/cam_K), mounted 1.6 m up, looking ahead.\n[[cameras]]\nfolder = {:?}\nrate_hz = {}\nloops = {}\npace_by = \"perception/front/navigability\"\n\
             # recorded frames, stamped as they go out: the graph runs on the wall clock\n\
             capture_time = \"publish\"\n\n\
             [cameras.model]\nname = \"front\"\nwidth = 1280\nheight = 720\nfx = 1487.75\nfy = 1471.06\ncx = 625.01\ncy = 376.48\nxyz_m = [0.0, 0.0, 1.6]\n",
            frames.display().to_string(),
            a.rate_hz,
            a.loops
        ),
    )?;
    let bridge_cfg = out.join("bridge.toml");
    std::fs::write(
        &bridge_cfg,
        format!(
            "robot = \"demo\"\nimport = []\n\n[zenoh]\nmode = \"peer\"\nlisten = [\"{endpoint}\"]\n\n\
             [[export]]\ntopic = \"camera/front/image\"\ndownsample = 2\ncompression = \"png\"\n\n\
             [[export]]\ntopic = \"health/camera-ingest\"\n\n[[export]]\ntopic = \"camera/front/info\"\n\n\
             [[export]]\ntopic = \"perception/front/navigability\"\ncompression = \"png\"\n\n\
             [[export]]\ntopic = \"cmd/velocity\"\n\n[[export]]\ntopic = \"nav/subgoal\"\n"
        ),
    )?;

    let root = std::env::current_dir()?;
    let model = root.join("deploy/models/twinlitenet.toml");
    if !model.exists() {
        bail!(
            "{} not found: run the demo from the repository root",
            model.display()
        );
    }
    let inference_cfg = out.join("inference.toml");
    std::fs::write(
        &inference_cfg,
        format!(
            "camera = \"front\"\nmodel_config = {:?}\n",
            model.display().to_string()
        ),
    )?;
    let subgoal_cfg = out.join("subgoal-selection.toml");
    std::fs::write(
        &subgoal_cfg,
        "method = \"povnav\"\ncamera = \"front\"\nrobot_width_m = 1.0\n",
    )?;
    let servo_cfg = out.join("velocity-servoing.toml");
    std::fs::write(
        &servo_cfg,
        "output_rate_hz = 20.0\nsubgoal_deadline_s = 0.5\n",
    )?;

    println!("farsight demo: camera-ingest -> inference -> subgoal-selection -> velocity-servoing, watched over zenoh");
    println!("  frames: {}", frames.display());
    println!("  output: {}", out.display());
    let bridge = start("bridge", &bridge_cfg, &prefix, &out.join("bridge.log"))?;
    let mut bridge = bridge;
    let mut ready = String::new();
    BufReader::new(bridge.0.stdout.take().expect("stdout")).read_line(&mut ready)?;
    if ready.trim() != "bridge ready" {
        bail!(
            "the bridge did not start; see {}",
            out.join("bridge.log").display()
        );
    }
    let net = NetBus::open(NetBus::config("peer", &[], &[endpoint])?, "demo")?;
    let mut images = net.slice_subscriber(&topics::camera_image("front"))?;
    let mut health = net.subscriber(&topics::health("camera-ingest"))?;
    let mut info = net.subscriber(&topics::camera_info("front"))?;
    let mut nav_images = net.slice_subscriber(&topics::navigability("front"))?;
    let mut commands = net.subscriber(&topics::velocity_command())?;
    let mut subgoals = net.subscriber(&topics::subgoal())?;
    // The robot side: pose at the origin facing east, a goal 200 m ahead.
    let robot = Bus::open_with(
        "demo-robot",
        &IpcSettings {
            prefix: Some(prefix.clone()),
            root: None,
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
    let _servo = start_ready("velocity-servoing", &servo_cfg, &prefix, &out)?;
    let _subgoal = start_ready("subgoal-selection", &subgoal_cfg, &prefix, &out)?;
    let _inference = start_ready("inference", &inference_cfg, &prefix, &out)?;
    std::fs::create_dir_all(out.join("navigability"))?;
    std::thread::sleep(Duration::from_millis(500));
    let started = Instant::now();
    let (mut tracking, mut v_sum, mut w_abs_max, mut last_subgoal) = (0u64, 0.0f64, 0.0f64, None);
    let ingest = start(
        "camera-ingest",
        &ingest_cfg,
        &prefix,
        &out.join("camera-ingest.log"),
    )?;

    let expected = a.loops as u64 * std::fs::read_dir(&frames)?.count() as u64;
    let (mut received, mut bytes, mut last_health, mut camera) = (0u64, 0usize, None, None);
    let deadline = Instant::now() + Duration::from_secs(60);
    while received < expected && Instant::now() < deadline {
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
        if h.encoding != PixelEncoding::PNG {
            bail!("expected PNG frames from the bridge, got {}", h.encoding);
        }
        received += 1;
        bytes += data.len();
        let name = out
            .join("frames")
            .join(format!("{:04}.png", h.stamp.frame_seq));
        std::fs::write(&name, &data)?;
        print!(
            "\r  frame {:>3}/{expected}  {}x{} png {:>4} kB  capture {} ms",
            h.stamp.frame_seq,
            h.width,
            h.height,
            data.len() / 1024,
            h.stamp.capture_time_ns / 1_000_000
        );
        std::io::stdout().flush().ok();
    }
    println!();
    let elapsed = started.elapsed().as_secs_f64();
    drop(ingest);
    std::thread::sleep(Duration::from_millis(300));
    if let Some(h) = health.latest()? {
        last_health = Some(h);
    }
    drop(bridge);

    let mut summary = String::new();
    summary += &format!(
        "received {received} of {expected} frames over zenoh in {elapsed:.1} s ({:.1} frames/s)\n",
        received as f64 / elapsed
    );
    summary += &format!(
        "mean PNG size {} kB (frames downsampled 2x by the bridge)\n",
        bytes / received.max(1) as usize / 1024
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
