//! `farsight-sim run`: the simulator as a robot in the stage graph. Each
//! frame it publishes the camera image (and depth and camera model), the
//! pose, the near-field costmap (`costmap/local`) and the goal, then takes the
//! velocity command the graph answers with and drives the robot for one frame
//! period of simulated time.
//!
//! With `--clock lockstep` (the default) the next frame waits for a command
//! stamped with the current frame, so a run is as fast as the graph and the
//! same for a seed whatever the machine's speed; `--clock realtime` runs at
//! the frame rate on the wall clock and takes whatever command is newest.
//! `--oracle` also publishes the class image as the perception output (the
//! navigability of road, trail, grass and field), standing in for the
//! inference stage; it is a named mode, never the default.

use crate::episode::{Outcome, PoseLog, Summary};
use crate::rng::SplitMix64;
use crate::sim_robot::{SimOptions, SimRobot};
use crate::world::class;
use anyhow::{Context, Result};
use farsight_interfaces::camera::{Camera, CameraModel, Mount};
use farsight_interfaces::message::Message;
use farsight_interfaces::msg::{
    CostCell, ImageHeader, PixelEncoding, PolarCell, Stamp, VelocityCommand, MAX_RANGE_EDGES,
};
use farsight_interfaces::topics;
use farsight_interfaces::transport::any::AnyPublisher;
use farsight_interfaces::transport::ipc::Bus;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ClockMode {
    Lockstep,
    Realtime,
}

/// Who drives the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Drive {
    /// The stage graph's velocity commands.
    Graph,
    /// [`crate::expert::Expert`]: A* over the true map, for training
    /// recordings; no graph needed, and the run is as fast as rendering.
    Expert,
}

#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    #[arg(long, default_value = "bug-trap")]
    pub scenario: String,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, value_enum, default_value = "lockstep")]
    pub clock: ClockMode,
    /// Camera frames (and control steps) per second of simulated time.
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    #[arg(long, default_value_t = 300.0)]
    pub max_time_s: f64,
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Standard deviation of the noise on the published position (m), as a
    /// GPS/odometry error; the robot itself drives the true pose.
    #[arg(long, default_value_t = 0.0)]
    pub pose_noise_m: f64,
    /// Standard deviation of the noise on the published yaw (degrees).
    #[arg(long, default_value_t = 0.0)]
    pub yaw_noise_deg: f64,
    /// Cameras to render and publish, by mount: `front`, `left`, `right`,
    /// `rear` (the same 120 degree pinhole looking 0, 90, -90, 180 degrees
    /// from the robot's heading). Each publishes camera/<name>/image, info
    /// and depth (and navigability with --oracle).
    #[arg(long, value_delimiter = ',', default_value = "front")]
    pub cameras: Vec<String>,
    /// Publish the rendered class image as perception/<camera>/navigability.
    #[arg(long)]
    pub oracle: bool,
    /// Publish FITAM's far field labelled from the true world as
    /// `bins/polar` (the "GT labels" row), standing in for inference and bin
    /// projection.
    #[arg(long)]
    pub far_field_oracle: bool,
    /// Lock-step: how long to wait for the graph's command before driving
    /// the frame with none (counted as a late command). Simulated time
    /// stands still while the graph works, so a slow or busy machine is
    /// never late; only a graph that has stopped answering (a stage down)
    /// should reach this, and then costs it per frame. Generous for that
    /// reason: at 0.5 s a machine busy with other work made late commands
    /// and changed the track.
    #[arg(long, default_value_t = 10.0, value_parser = parse_timeout_s)]
    pub command_timeout_s: f64,
    /// Lock-step: also wait, after the command, for these instances to
    /// report the frame on health/<name> (the recorder, `farsight record
    /// --ack`), so nothing runs ahead of them. One that does not answer in
    /// --command-timeout-s is warned about and no longer waited for.
    #[arg(long, value_delimiter = ',')]
    pub await_health: Vec<String>,
    /// The simulated base obeys each command for its time-to-live from
    /// receipt (`ttl_ms`), at most this long (s), then stops: a dead or
    /// frozen command writer stops the robot (farsight_interfaces::base).
    #[arg(long, default_value_t = 1.0)]
    pub base_max_ttl_s: f64,
    /// When an operator steps in: `carry-back` (stuck in place: 3 m back
    /// along the track) or `operator` (LRN section IV: not making progress
    /// by the expert's cost to go: face the goal, then walk it).
    #[arg(long, default_value = "carry-back", value_parser = crate::episode::InterventionRule::named)]
    pub intervention_rule: crate::episode::InterventionRule,
    /// The robot's disc footprint (m); a Jackal is about 0.25.
    #[arg(long, default_value_t = crate::robot::RobotLimits::default().radius_m)]
    pub robot_radius_m: f64,
    /// What the near-field sensor reports: `true-cost`, or
    /// `height-threshold` (HIP's geometric costmap: lethal above 0.5 m,
    /// free below, so tall grass looks lethal and shrubs and stones free).
    #[arg(long, default_value = "true-cost", value_parser = parse_near_field)]
    pub near_field: crate::sensor::CostModel,
    #[arg(long, default_value = "out/sim")]
    pub out: PathBuf,
    /// Who drives: the graph's commands, or the expert (A* on the true map).
    #[arg(long, value_enum, default_value = "graph")]
    pub drive: Drive,
    /// Also write what the simulator publishes (each camera's image and
    /// info, the pose, the local costmap) into this MCAP file, every frame,
    /// from this process: nothing skipped, whatever the pace.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// With --record: write camera frames only every n-th frame (poses and
    /// local costmaps still every frame); training sets use every 5th.
    #[arg(long, default_value_t = 1)]
    pub record_every: u64,
}

/// An instance the lock-step loop waits for after each command
/// (`--await-health`): it reports the frame it has taken in as its health
/// report's frame number.
struct AwaitedAnswer {
    name: String,
    health: farsight_interfaces::transport::ipc::Subscriber<farsight_interfaces::msg::StageHealth>,
    answered: u64,
    given_up: bool,
}

impl AwaitedAnswer {
    fn open(bus: &Bus, name: &str) -> Result<Self> {
        Ok(Self {
            name: name.to_string(),
            health: bus.subscriber(&topics::health(name))?,
            answered: 0,
            given_up: false,
        })
    }

    /// Waits until frame `k` is reported, at most `timeout`; one that does
    /// not answer in time is not waited for again (a dead recorder must not
    /// slow the drive by a timeout per frame).
    fn wait_for(&mut self, k: u64, timeout: Duration, bus: &Bus) -> Result<()> {
        let end = Instant::now() + timeout;
        while !self.given_up && self.answered < k {
            if let Some(h) = self.health.latest()? {
                self.answered = self.answered.max(h.stamp.frame_seq);
                continue;
            }
            if Instant::now() >= end || bus.termination_requested() {
                eprintln!(
                    "frame {k}: health/{} did not report it in {:.1} s; not waiting for it any more",
                    self.name,
                    timeout.as_secs_f64()
                );
                self.given_up = true;
            } else {
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        Ok(())
    }
}

/// The simulator's own recording (see `--record`).
struct SimRecorder(farsight_recording::write::RecordingWriter);

impl SimRecorder {
    fn message<M: serde::Serialize>(&mut self, topic: &str, stamp: Stamp, msg: &M) -> Result<()> {
        let bytes = farsight_interfaces::transport::wire::encode_message(msg)?;
        self.0.write(topic, stamp, stamp.capture_time_ns, &bytes)?;
        Ok(())
    }
}

/// The default simulated camera's horizontal field of view. Wide, as on
/// the papers' field robots: at 90 degrees a tree beside the robot leaves
/// the view while the robot is still passing it, and the level camera sees
/// no ground nearer than 1.8 m; at 120 degrees that is 1.0 m.
pub const FRONT_HFOV_DEG: f64 = 120.0;

/// The default simulated camera: a level pinhole with [`FRONT_HFOV_DEG`],
/// 1 m up.
pub fn front_camera(width: u32, height: u32) -> Camera {
    named_camera("front", width, height).expect("front is a known camera")
}

/// The cameras `farsight-sim run --cameras` knows: name and yaw from the
/// robot's heading (degrees, counter-clockwise).
pub const CAMERA_MOUNTS: [(&str, f64); 4] = [
    ("front", 0.0),
    ("left", 90.0),
    ("right", -90.0),
    ("rear", 180.0),
];

/// One of [`CAMERA_MOUNTS`] as the simulator's 120 degree pinhole, 1 m up,
/// with its index as the camera id.
pub fn named_camera(name: &str, width: u32, height: u32) -> Result<Camera> {
    let Some(id) = CAMERA_MOUNTS.iter().position(|(n, _)| *n == name) else {
        anyhow::bail!(
            "unknown camera {name:?}; the simulator mounts {}",
            CAMERA_MOUNTS.map(|(n, _)| n).join(", ")
        );
    };
    let f = width as f64 / 2.0 / (FRONT_HFOV_DEG.to_radians() / 2.0).tan();
    Ok(Camera::new(
        id as u32,
        name,
        CameraModel::pinhole(
            width,
            height,
            f,
            f,
            (width as f64 - 1.0) / 2.0,
            (height as f64 - 1.0) / 2.0,
        ),
        Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 0.0, CAMERA_MOUNTS[id].1]),
    ))
}

/// A frame's capture time on the simulated clock (the stamps' time base,
/// which the servo's `clock = "stamps"` measures its ramps on).
pub fn capture_time_ns(time_s: f64) -> u64 {
    (time_s * 1e9) as u64
}

/// The pose the robot reports: the true one plus independent Gaussian noise
/// on position (`sigma_m` per axis) and yaw, drawn from the run's seeded
/// generator so a noisy run is still the same for a seed.
pub fn reported_pose(
    truth: [f64; 3],
    sigma_m: f64,
    sigma_yaw_rad: f64,
    rng: &mut SplitMix64,
) -> [f64; 3] {
    if sigma_m == 0.0 && sigma_yaw_rad == 0.0 {
        return truth;
    }
    [
        truth[0] + sigma_m * rng.normal(),
        truth[1] + sigma_m * rng.normal(),
        truth[2] + sigma_yaw_rad * rng.normal(),
    ]
}

/// Pixels per map cell of the map PNG: small scenario maps are scaled up
/// (whole pixels per cell) to be readable.
pub fn map_scale(map_width: usize, map_height: usize) -> usize {
    (800 / map_width.max(map_height).max(1)).clamp(1, 8)
}

/// The top-left pixel of the map PNG's block for world point (x, y), if it
/// is on the map (north up, [`map_scale`] pixels per cell).
pub fn map_pixel(world: &crate::world::World, x_m: f64, y_m: f64) -> Option<(usize, usize)> {
    let (cx, cy) = world.cell_of(x_m, y_m);
    if !world.contains(cx, cy) {
        return None;
    }
    let k = map_scale(world.width, world.height);
    Some((cx as usize * k, (world.height - 1 - cy as usize) * k))
}

/// `--near-field`'s values, named in the error.
pub fn parse_near_field(name: &str) -> Result<crate::sensor::CostModel, String> {
    crate::sensor::CostModel::named(name).ok_or_else(|| {
        format!("near-field sensor {name:?}: expected \"true-cost\" or \"height-threshold\"")
    })
}

/// A wait in seconds from the command line: finite, above 0, at most a day
/// (a `Duration` cannot hold NaN, a negative or an unbounded wait).
pub fn parse_timeout_s(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 86_400.0 => Ok(v),
        Ok(v) => Err(format!("{v} s: expected 0 < seconds <= 86400")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// Classes a ground robot may drive on (the oracle's navigability).
pub fn navigable_class(c: u8) -> bool {
    matches!(
        c,
        class::ROAD | class::TRAIL | class::GRASS | class::FIELD | class::TALL_GRASS
    )
}

impl RunArgs {
    /// The simulated robot these arguments describe.
    pub fn sim_options(&self) -> SimOptions {
        SimOptions {
            scenario: self.scenario.clone(),
            seed: self.seed,
            rate_hz: self.rate_hz,
            max_time_s: self.max_time_s,
            width: self.width,
            height: self.height,
            pose_noise_m: self.pose_noise_m,
            yaw_noise_deg: self.yaw_noise_deg,
            cameras: self.cameras.clone(),
            oracle: self.oracle,
            far_field_oracle: self.far_field_oracle,
            base_max_ttl_s: self.base_max_ttl_s,
            intervention: self.intervention_rule,
            near_field: self.near_field,
            robot_radius_m: self.robot_radius_m,
            render_threads: 0,
        }
    }
}

/// The most bytes one message of a topic the simulator publishes carries.
fn max_slice_bytes(topic: &str, (w, h): (u32, u32), local_side: usize) -> usize {
    let pixels = w as usize * h as usize;
    match topic.rsplit('/').next() {
        Some("image") => pixels * 3,
        Some("depth") => pixels * 4,
        Some("navigability") => pixels,
        Some("local") => local_side * local_side * std::mem::size_of::<CostCell>(),
        Some("polar") => 360 * (MAX_RANGE_EDGES - 1) * std::mem::size_of::<PolarCell>(),
        _ => 0,
    }
}

pub fn run(a: RunArgs) -> Result<Summary> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut sim = SimRobot::new(&a.sim_options())?;
    let bus = Bus::open("sim")?;
    // One publisher per topic the simulator senses, opened before it
    // announces itself: the first frame's every message has a port.
    let mut publishers = std::collections::BTreeMap::new();
    for topic in sim.topics() {
        let bytes = max_slice_bytes(&topic, (a.width, a.height), sim.local_costmap_side());
        let port = AnyPublisher::open(&bus, &topic, bytes)?;
        publishers.insert(topic, port);
    }
    let goals = bus.publisher(&topics::goal())?;
    let commands = bus.subscriber(&topics::velocity_command())?;
    let mut awaited = a
        .await_health
        .iter()
        .map(|name| AwaitedAnswer::open(&bus, name))
        .collect::<Result<Vec<_>>>()?;
    let goal = sim.goal();
    goals.publish(&goal)?;
    println!("farsight-sim ready");
    let s = &sim.episode.scenario;
    eprintln!(
        "{}: start ({:.0}, {:.0}), goal ({:.0}, {:.0}), {:.0} m away; clock {:?}",
        s.name,
        s.start[0],
        s.start[1],
        s.goal[0],
        s.goal[1],
        (s.goal[0] - s.start[0]).hypot(s.goal[1] - s.start[1]),
        a.clock
    );

    let trace_path = a.out.join("poses.csv");
    let mut trace = PoseLog::create(&trace_path)
        .with_context(|| format!("creating {}", trace_path.display()))?;
    let dt = 1.0 / a.rate_hz;
    let mut late = 0u32;
    let mut expert = match a.drive {
        Drive::Graph => None,
        Drive::Expert => Some(
            crate::expert::Expert::new(
                &sim.episode.scenario.world,
                [sim.episode.robot.x_m, sim.episode.robot.y_m],
                sim.episode.scenario.goal,
                1.5,
            )
            .with_context(|| {
                format!(
                    "--drive expert: no path to the goal in {} seed {}",
                    a.scenario, a.seed
                )
            })?,
        ),
    };
    let mut recorder = match &a.record {
        Some(p) => Some(SimRecorder(
            farsight_recording::write::RecordingWriter::create(p, false)
                .with_context(|| format!("--record {}", p.display()))?,
        )),
        None => None,
    };
    if let Some(rec) = &mut recorder {
        rec.message(topics::goal().name(), Stamp::default(), &goal)?;
    }
    let wall_start = Instant::now();
    for k in 1u64.. {
        if bus.termination_requested() {
            // SIGTERM/SIGINT (iceoryx2's handler keeps them from ending the
            // process): stop, leaving the trace and map written.
            eprintln!("stopped: termination requested");
            break;
        }
        let r = sim.episode.robot;
        // Lock-step: the simulated clock (the graph runs on the stamps'
        // clock). Real time: the wall clock, as a robot's camera stamps its
        // frames, so stages on the wall clock judge their age truly.
        let stamp = sim.next_stamp(match a.clock {
            ClockMode::Lockstep => None,
            ClockMode::Realtime => Some(farsight_interfaces::clock::Clock::now_ns(
                &farsight_interfaces::clock::WallClock,
            )),
        });
        let sensed = sim.sense(stamp, |_| true);
        if let Some(rec) = &mut recorder {
            // Poses and local costmaps every frame; camera frames (image
            // and info) every `record_every`-th.
            let cameras_too = k % a.record_every.max(1) == 1 % a.record_every.max(1);
            for (topic, m) in &sensed {
                let camera = topic.ends_with("/image") || topic.ends_with("/info");
                let kept = match m {
                    Message::Pose(_) | Message::Costmap(_) => true,
                    _ => camera && cameras_too,
                };
                if kept {
                    rec.0
                        .write(topic, stamp, stamp.capture_time_ns, &m.to_wire()?)?;
                }
            }
        }
        for (topic, m) in sensed {
            publishers
                .get_mut(&topic)
                .expect("a port per sensed topic")
                .publish_message(m)?;
        }
        goals.deliver_history()?;

        let mut older_answer = None;
        let command = match (&mut expert, a.clock) {
            (Some(e), _) => {
                let (v, w) = e.command(&sim.episode.scenario.world, r.pose(), dt);
                Some(VelocityCommand {
                    stamp,
                    linear_mps: v as f32,
                    angular_radps: w as f32,
                    ..Default::default()
                })
            }
            (None, clock) => match clock {
                ClockMode::Lockstep => {
                    let timeout = Duration::from_secs_f64(a.command_timeout_s);
                    let end = Instant::now() + timeout;
                    let command = loop {
                        match commands.latest()? {
                            Some(c) if c.stamp.frame_seq >= k => break Some(c),
                            // An answer to an earlier frame: the graph
                            // paired this frame's input with older ones.
                            Some(c) if c.stamp.frame_seq > 0 => {
                                older_answer = Some(c.stamp.frame_seq)
                            }
                            _ => {}
                        }
                        if Instant::now() >= end || bus.termination_requested() {
                            break None;
                        }
                        std::thread::sleep(Duration::from_micros(500));
                    };
                    if command.is_some() {
                        for w in &mut awaited {
                            w.wait_for(k, timeout, &bus)?;
                        }
                    }
                    command
                }
                ClockMode::Realtime => {
                    let due = wall_start + Duration::from_secs_f64(k as f64 * dt);
                    std::thread::sleep(due.saturating_duration_since(Instant::now()));
                    commands.latest()?
                }
            },
        };
        // The robot is a base like any other: it holds the last command it
        // received for that command's time-to-live, then stops.
        let (fresh, outcome) = sim.drive(command);
        if !fresh {
            late += 1;
            if late == 1 || late.is_multiple_of(100) {
                let why = match older_answer {
                    Some(j) => format!("the newest answer was to frame {j}"),
                    None => "is a stage down?".to_string(),
                };
                eprintln!(
                    "frame {k}: no finite command from the graph ({late} late so far); {why}"
                );
            }
        }
        let episode = &sim.episode;
        trace.record(episode)?;
        if k % (5.0 * a.rate_hz).max(1.0) as u64 == 0 {
            trace.flush()?;
            eprintln!(
                "t {:6.1} s  goal {:6.1} m  v {:4.2} m/s  collisions {}  interventions {}  (wall {:.0} s)",
                episode.time_s,
                episode.goal_distance_m(),
                episode.robot.linear_mps,
                episode.robot.collisions,
                episode.interventions,
                wall_start.elapsed().as_secs_f64()
            );
        }
        if outcome != Outcome::Driving {
            break;
        }
    }
    trace.flush()?;
    if let Some(rec) = recorder {
        rec.0.finish()?;
    }
    let summary = sim.episode.summary();
    let (mw, mh, cells) = sim.episode.map_rgb();
    let k = map_scale(mw, mh);
    let (pw, ph) = (mw * k, mh * k);
    let rgb: Vec<u8> = (0..ph)
        .flat_map(|y| (0..pw).map(move |x| (y / k) * mw + x / k))
        .flat_map(|i| [cells[i * 3], cells[i * 3 + 1], cells[i * 3 + 2]])
        .collect();
    let header = ImageHeader::packed(
        Stamp::default(),
        0,
        pw as u32,
        ph as u32,
        PixelEncoding::RGB8,
    );
    let map_path = a.out.join(format!("{}-map.png", summary.scenario));
    std::fs::write(&map_path, farsight_imaging::encode_png(&header, &rgb)?)
        .with_context(|| format!("writing {}", map_path.display()))?;
    let text = format!(
        "scenario = {:?}\nseed = {}\noutcome = {:?}\ntime_s = {:.1}\ndistance_m = {:.1}\ntraversal_cost_s = {:.1}\ncollisions = {}\ninterventions = {}\nfinal_goal_distance_m = {:.1}\nlate_commands = {}\nwall_s = {:.1}\n",
        summary.scenario,
        a.seed,
        format!("{:?}", summary.outcome).to_lowercase(),
        summary.time_s,
        summary.distance_m,
        summary.traversal_cost_s,
        summary.collisions,
        summary.interventions,
        summary.final_goal_distance_m,
        late,
        wall_start.elapsed().as_secs_f64()
    );
    std::fs::write(a.out.join("summary.toml"), &text)?;
    println!("{text}map: {}", map_path.display());
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_timeout_that_no_duration_holds_is_refused_naming_the_value() {
        assert_eq!(parse_timeout_s("120"), Ok(120.0));
        for bad in ["nan", "-1", "0", "inf", "1e9"] {
            let e = parse_timeout_s(bad).unwrap_err();
            assert!(e.contains("expected 0 < seconds <= 86400"), "{bad}: {e}");
        }
        assert!(parse_timeout_s("soon").unwrap_err().contains("\"soon\""));
    }

    #[test]
    fn reported_pose_noise_has_the_asked_spread_and_none_means_the_truth() {
        let mut rng = SplitMix64::new(4);
        let truth = [10.0, -5.0, 0.3];
        assert_eq!(reported_pose(truth, 0.0, 0.0, &mut rng), truth);
        let n = 4000;
        let draws: Vec<[f64; 3]> = (0..n)
            .map(|_| reported_pose(truth, 0.5, 0.05, &mut rng))
            .collect();
        for (k, sigma) in [(0, 0.5), (1, 0.5), (2, 0.05)] {
            let mean = draws.iter().map(|d| d[k]).sum::<f64>() / n as f64;
            let sd = (draws.iter().map(|d| (d[k] - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
            assert!(
                (mean - truth[k]).abs() < 4.0 * sigma / (n as f64).sqrt(),
                "axis {k}: mean {mean}"
            );
            assert!(
                (sd / sigma - 1.0).abs() < 0.06,
                "axis {k}: sd {sd} for {sigma}"
            );
        }
    }
}
