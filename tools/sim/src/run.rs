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

use crate::episode::{Episode, EpisodeConfig, Outcome, PoseLog, Summary};
use crate::render::{Frame, Renderer};
use crate::rng::SplitMix64;
use crate::scenario::scenario;
use crate::sensor::NearFieldSensor;
use crate::world::class;
use anyhow::{Context, Result};
use farsight_interfaces::camera::{Camera, CameraModel, Mount};
use farsight_interfaces::msg::{
    CameraInfo, GoalKind, ImageHeader, NavGoal, PixelEncoding, Pose, Stamp, VelocityCommand,
};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, Publisher, SlicePublisher};
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
    /// Lock-step: how long to wait for the graph's command before driving
    /// the frame with none (counted as a late command). Simulated time
    /// stands still while the graph works, so a slow or busy machine is
    /// never late; only a graph that has stopped answering (a stage down)
    /// should reach this, and then costs it per frame. Generous for that
    /// reason: at 0.5 s a machine busy with other work made late commands
    /// and changed the track.
    #[arg(long, default_value_t = 10.0)]
    pub command_timeout_s: f64,
    /// The simulated base obeys each command for its time-to-live from
    /// receipt (`ttl_ms`), at most this long (s), then stops: a dead or
    /// frozen command writer stops the robot (farsight_interfaces::base).
    #[arg(long, default_value_t = 1.0)]
    pub base_max_ttl_s: f64,
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

/// The simulator's own recording (see `--record`).
struct SimRecorder(farsight_recording::write::RecordingWriter);

impl SimRecorder {
    fn message<M: serde::Serialize>(&mut self, topic: &str, stamp: Stamp, msg: &M) -> Result<()> {
        let bytes = farsight_interfaces::transport::wire::encode_message(msg)?;
        self.0.write(topic, stamp, stamp.capture_time_ns, &bytes)?;
        Ok(())
    }

    fn slice<H: serde::Serialize, E: bytemuck::Pod>(
        &mut self,
        topic: &str,
        stamp: Stamp,
        header: &H,
        data: &[E],
    ) -> Result<()> {
        let bytes = farsight_interfaces::transport::wire::encode_slice(header, data)?;
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

/// One simulated camera: its renderer, its last frame and its publishers.
struct CameraRig {
    camera: Camera,
    renderer: Renderer,
    frame: Frame,
    images: SlicePublisher<ImageHeader, u8>,
    depths: SlicePublisher<ImageHeader, u8>,
    infos: Publisher<CameraInfo>,
    oracle: Option<SlicePublisher<ImageHeader, u8>>,
}

impl CameraRig {
    fn open(bus: &Bus, camera: Camera, oracle: bool) -> Result<Self> {
        let (w, h) = (camera.model.width as usize, camera.model.height as usize);
        let name = camera.name.as_str();
        Ok(Self {
            renderer: Renderer::new(&camera, 150.0),
            frame: Frame::default(),
            images: bus.slice_publisher(&topics::camera_image(name), w * h * 3)?,
            depths: bus.slice_publisher(&topics::depth(name), w * h * 4)?,
            infos: bus.publisher(&topics::camera_info(name))?,
            oracle: if oracle {
                Some(bus.slice_publisher(&topics::navigability(name), w * h)?)
            } else {
                None
            },
            camera,
        })
    }

    /// Writes the last rendered frame's image and camera model.
    fn record(&self, rec: &mut SimRecorder, stamp: Stamp) -> Result<()> {
        let (w, h) = (self.camera.model.width, self.camera.model.height);
        rec.message(
            topics::camera_info(&self.camera.name).name(),
            stamp,
            &self.camera.to_info(stamp),
        )?;
        rec.slice(
            topics::camera_image(&self.camera.name).name(),
            stamp,
            &ImageHeader::packed(stamp, self.camera.id, w, h, PixelEncoding::RGB8),
            &self.frame.rgb,
        )
    }

    /// Renders the robot's view and publishes info, depth, the oracle's
    /// navigability and the image (last: a stage woken by the image finds
    /// the rest already there). Depth and navigability are written straight
    /// into the shared-memory samples: no per-frame buffers.
    fn publish(&mut self, world: &crate::world::World, pose: [f64; 3], stamp: Stamp) -> Result<()> {
        let (w, h) = (self.camera.model.width, self.camera.model.height);
        let n = w as usize * h as usize;
        let id = self.camera.id;
        self.renderer.render(world, pose, &mut self.frame);
        self.infos.publish(&self.camera.to_info(stamp))?;
        let frame = &self.frame;
        self.depths.publish_with(n * 4, |buf| {
            for (b, d) in buf.chunks_exact_mut(4).zip(&frame.depth_m) {
                b.copy_from_slice(&d.to_le_bytes());
            }
            ImageHeader::packed(stamp, id, w, h, PixelEncoding::F32)
        })?;
        if let Some(o) = &self.oracle {
            o.publish_with(n, |buf| {
                for (b, &c) in buf.iter_mut().zip(&frame.class_ids) {
                    *b = if navigable_class(c) { 255 } else { 0 };
                }
                ImageHeader::packed(stamp, id, w, h, PixelEncoding::MONO8)
            })?;
        }
        self.images.publish_copy(
            ImageHeader::packed(stamp, id, w, h, PixelEncoding::RGB8),
            &frame.rgb,
        )?;
        Ok(())
    }
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

/// Classes a ground robot may drive on (the oracle's navigability).
pub fn navigable_class(c: u8) -> bool {
    matches!(c, class::ROAD | class::TRAIL | class::GRASS | class::FIELD)
}

pub fn run(a: RunArgs) -> Result<Summary> {
    let s = scenario(&a.scenario, a.seed)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let sensor = NearFieldSensor::default();
    let bus = Bus::open("sim")?;
    anyhow::ensure!(!a.cameras.is_empty(), "--cameras: name at least one camera");
    let mut rigs = a
        .cameras
        .iter()
        .map(|name| CameraRig::open(&bus, named_camera(name, a.width, a.height)?, a.oracle))
        .collect::<Result<Vec<_>>>()?;
    let poses = bus.publisher(&topics::pose())?;
    let goals = bus.publisher(&topics::goal())?;
    let side = (2.0 * sensor.range_m + 1.0) as usize;
    let locals = bus.slice_publisher(&topics::costmap("local"), side * side)?;
    let commands = bus.subscriber(&topics::velocity_command())?;
    let goal = NavGoal {
        kind: GoalKind::LOCAL,
        x_m: s.goal[0],
        y_m: s.goal[1],
        tolerance_m: 2.0,
        ..Default::default()
    };
    goals.publish(&goal)?;
    println!("farsight-sim ready");
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

    let cfg = EpisodeConfig {
        max_time_s: a.max_time_s,
        ..Default::default()
    };
    let mut episode = Episode::new(s, cfg);
    let trace_path = a.out.join("poses.csv");
    let mut trace = PoseLog::create(&trace_path)
        .with_context(|| format!("creating {}", trace_path.display()))?;
    let dt = 1.0 / a.rate_hz;
    let mut late = 0u32;
    anyhow::ensure!(
        a.base_max_ttl_s.is_finite() && a.base_max_ttl_s > 0.0,
        "--base-max-ttl-s {}: expected a positive time in seconds (the base would never move)",
        a.base_max_ttl_s
    );
    let mut base = farsight_interfaces::base::CommandGate::new(a.base_max_ttl_s);
    anyhow::ensure!(
        a.pose_noise_m >= 0.0 && a.yaw_noise_deg >= 0.0,
        "--pose-noise-m {} / --yaw-noise-deg {}: noise must be 0 or more",
        a.pose_noise_m,
        a.yaw_noise_deg
    );
    let mut noise = SplitMix64::new(a.seed ^ 0x9053);
    let mut expert = match a.drive {
        Drive::Graph => None,
        Drive::Expert => Some(
            crate::expert::Expert::new(
                &episode.scenario.world,
                [episode.robot.x_m, episode.robot.y_m],
                episode.scenario.goal,
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
        let r = episode.robot;
        // Lock-step: the simulated clock (the graph runs on the stamps'
        // clock). Real time: the wall clock, as a robot's camera stamps its
        // frames, so stages on the wall clock judge their age truly.
        let stamp = Stamp::new(
            k,
            match a.clock {
                ClockMode::Lockstep => capture_time_ns(episode.time_s),
                ClockMode::Realtime => farsight_interfaces::clock::Clock::now_ns(
                    &farsight_interfaces::clock::WallClock,
                ),
            },
        );
        let [px, py, pyaw] = reported_pose(
            r.pose(),
            a.pose_noise_m,
            a.yaw_noise_deg.to_radians(),
            &mut noise,
        );
        // Height is the ground under the robot (the camera rides on it), so
        // recorded trajectories project into past frames on hills too.
        let (cx, cy) = episode.scenario.world.cell_of(r.x_m, r.y_m);
        let ground_m = episode.scenario.world.ground_m(cx, cy) as f64;
        let pose = Pose {
            stamp,
            position_m: [px, py, ground_m],
            yaw_rad: pyaw,
            linear_mps: r.linear_mps as f32,
            angular_radps: r.angular_radps as f32,
            ..Default::default()
        };
        poses.publish(&pose)?;
        let (lh, lc) = sensor.observe(&episode.scenario.world, r.x_m, r.y_m, stamp);
        locals.publish_copy(lh, &lc)?;
        for rig in &mut rigs {
            rig.publish(&episode.scenario.world, r.pose(), stamp)?;
        }
        goals.deliver_history()?;
        if let Some(rec) = &mut recorder {
            rec.message(topics::pose().name(), stamp, &pose)?;
            rec.slice(topics::costmap("local").name(), stamp, &lh, &lc)?;
            if k % a.record_every.max(1) == 1 % a.record_every.max(1) {
                for rig in &rigs {
                    rig.record(rec, stamp)?;
                }
            }
        }

        let command = match (&mut expert, a.clock) {
            (Some(e), _) => Some(VelocityCommand {
                stamp,
                linear_mps: 0.0,
                angular_radps: 0.0,
                ..Default::default()
            })
            .map(|mut c| {
                let (v, w) = e.command(&episode.scenario.world, r.pose(), dt);
                (c.linear_mps, c.angular_radps) = (v as f32, w as f32);
                c
            }),
            (None, clock) => match clock {
                ClockMode::Lockstep => {
                    let end = Instant::now() + Duration::from_secs_f64(a.command_timeout_s);
                    loop {
                        match commands.latest()? {
                            Some(c) if c.stamp.frame_seq >= k => break Some(c),
                            _ if Instant::now() >= end || bus.termination_requested() => {
                                break None
                            }
                            _ => std::thread::sleep(Duration::from_micros(500)),
                        }
                    }
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
        let fresh =
            command.is_some_and(|c| c.linear_mps.is_finite() && c.angular_radps.is_finite());
        if let Some(c) = command {
            base.receive(c, episode.time_s);
        }
        if !fresh {
            late += 1;
            if late == 1 || late.is_multiple_of(100) {
                eprintln!(
                    "frame {k}: no finite command from the graph ({late} late so far); is a stage down?"
                );
            }
        }
        let (v, w_) = base.command(episode.time_s);
        let outcome = episode.step((v, w_), dt);
        trace.record(&episode)?;
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
    let summary = episode.summary();
    let (mw, mh, cells) = episode.map_rgb();
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
