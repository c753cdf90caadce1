//! The simulated robot as plain messages: each frame it senses (the pose,
//! the near-field costmap `costmap/local`, and for each camera its model,
//! depth, the oracle's navigability and the image) as owned
//! [`Message`]s, and it drives one frame period with the command it is
//! given, through a base's time-to-live gate. `farsight-sim run` publishes
//! these messages on iceoryx2; the in-process executor hands them to the
//! stages directly. Both therefore feed a graph the same inputs, frame by
//! frame.

use crate::episode::{Episode, EpisodeConfig, Outcome};
use crate::labels::{ground_truth_bins, LabelRules};
use crate::render::{Channels, Frame, Renderer};
use crate::rng::SplitMix64;
use crate::run::{capture_time_ns, named_camera, navigable_class, reported_pose};
use crate::scenario::scenario;
use crate::sensor::NearFieldSensor;
use anyhow::{ensure, Result};
use farsight_costmap_fusion::swath::PolarGeometry;
use farsight_interfaces::base::CommandGate;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::fixed::FixedVec;
use farsight_interfaces::message::{Image, Message, Sliced};
use farsight_interfaces::msg::{
    GoalKind, ImageHeader, NavGoal, PixelEncoding, PolarBinsHeader, Pose, Stamp, VelocityCommand,
};
use farsight_interfaces::topics;

/// What a simulated run is: the world, the robot's sensors and its base.
#[derive(Debug, Clone)]
pub struct SimOptions {
    pub scenario: String,
    pub seed: u64,
    /// Camera frames (and control steps) per second of simulated time.
    pub rate_hz: f64,
    pub max_time_s: f64,
    pub width: u32,
    pub height: u32,
    pub pose_noise_m: f64,
    pub yaw_noise_deg: f64,
    /// Cameras by mount (`front`, `left`, `right`, `rear`).
    pub cameras: Vec<String>,
    /// Also sense each camera's class image as its navigability.
    pub oracle: bool,
    /// Also sense the far field as FITAM's polar bins labelled from the
    /// true world (`bins/polar`; FITAM's "GT labels" row).
    pub far_field_oracle: bool,
    /// The base obeys a command at most this long (s) after receipt.
    pub base_max_ttl_s: f64,
    /// When an operator steps in and what they do.
    pub intervention: crate::episode::InterventionRule,
    /// The robot's disc footprint (m): 0.4 by default; a Clearpath Jackal
    /// (0.43 m wide, POVNav section 5) is about 0.25.
    pub robot_radius_m: f64,
    /// What the near-field sensor reports: true costs, or HIP's height
    /// threshold (`crate::sensor::CostModel`).
    pub near_field: crate::sensor::CostModel,
    /// Threads each camera's renderer uses (0: the machine's cores, at
    /// most 4). A benchmark running trials side by side gives each fewer.
    pub render_threads: usize,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            scenario: "bug-trap".into(),
            seed: 1,
            rate_hz: 10.0,
            max_time_s: 300.0,
            width: 640,
            height: 360,
            pose_noise_m: 0.0,
            yaw_noise_deg: 0.0,
            cameras: vec!["front".into()],
            oracle: false,
            far_field_oracle: false,
            base_max_ttl_s: 1.0,
            intervention: Default::default(),
            robot_radius_m: crate::robot::RobotLimits::default().radius_m,
            near_field: crate::sensor::CostModel::TrueCost,
            render_threads: 0,
        }
    }
}

struct SimCamera {
    camera: Camera,
    renderer: Renderer,
    frame: Frame,
    topics: [String; 4],
}

/// The robot in its world, frame by frame.
pub struct SimRobot {
    pub episode: Episode,
    options: SimOptions,
    sensor: NearFieldSensor,
    cameras: Vec<SimCamera>,
    goal: NavGoal,
    noise: SplitMix64,
    base: CommandGate,
    frame_seq: u64,
}

impl SimRobot {
    pub fn new(options: &SimOptions) -> Result<Self> {
        ensure!(
            !options.cameras.is_empty(),
            "--cameras: name at least one camera"
        );
        ensure!(
            options.base_max_ttl_s.is_finite() && options.base_max_ttl_s > 0.0,
            "--base-max-ttl-s {}: expected a positive time in seconds (the base would never move)",
            options.base_max_ttl_s
        );
        ensure!(
            options.pose_noise_m >= 0.0 && options.yaw_noise_deg >= 0.0,
            "--pose-noise-m {} / --yaw-noise-deg {}: noise must be 0 or more",
            options.pose_noise_m,
            options.yaw_noise_deg
        );
        ensure!(
            options.rate_hz.is_finite() && options.rate_hz > 0.0,
            "--rate-hz {}: expected frames per second above 0",
            options.rate_hz
        );
        let s = scenario(&options.scenario, options.seed)?;
        let cameras = options
            .cameras
            .iter()
            .map(|name| {
                let camera = named_camera(name, options.width, options.height)?;
                let n = camera.name.as_str();
                Ok(SimCamera {
                    topics: [
                        topics::camera_info(n).name().to_string(),
                        topics::depth(n).name().to_string(),
                        topics::navigability(n).name().to_string(),
                        topics::camera_image(n).name().to_string(),
                    ],
                    renderer: {
                        let mut r = Renderer::new(&camera, 150.0);
                        if options.render_threads > 0 {
                            r.threads = options.render_threads;
                        }
                        r
                    },
                    frame: Frame::default(),
                    camera,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let goal = NavGoal {
            kind: GoalKind::LOCAL,
            x_m: s.goal[0],
            y_m: s.goal[1],
            tolerance_m: 2.0,
            ..Default::default()
        };
        ensure!(
            options.robot_radius_m.is_finite() && options.robot_radius_m > 0.0,
            "--robot-radius-m {}: expected a radius above 0 m",
            options.robot_radius_m
        );
        let config = EpisodeConfig::with_rules(
            options.max_time_s,
            options.intervention,
            options.robot_radius_m,
        );
        Ok(Self {
            episode: Episode::new(s, config),
            sensor: NearFieldSensor {
                cost_model: options.near_field,
                ..NearFieldSensor::default()
            },
            cameras,
            goal,
            noise: SplitMix64::new(options.seed ^ 0x9053),
            base: CommandGate::new(options.base_max_ttl_s),
            frame_seq: 0,
            options: options.clone(),
        })
    }

    /// The goal, published once (and kept as history for late subscribers).
    pub fn goal(&self) -> NavGoal {
        self.goal
    }

    /// The near-field costmap's side in cells (its slice length is the square).
    pub fn local_costmap_side(&self) -> usize {
        (2.0 * self.sensor.range_m + 1.0) as usize
    }

    /// Every topic [`Self::sense`] may write, in its order.
    pub fn topics(&self) -> Vec<String> {
        let mut out = vec![
            topics::pose().name().to_string(),
            topics::costmap("local").name().to_string(),
        ];
        if self.options.far_field_oracle {
            out.push(topics::polar_bins().name().to_string());
        }
        for cam in &self.cameras {
            for (i, t) in cam.topics.iter().enumerate() {
                if i != 2 || self.options.oracle {
                    out.push(t.clone());
                }
            }
        }
        out
    }

    /// The frame period, s.
    pub fn dt_s(&self) -> f64 {
        1.0 / self.options.rate_hz
    }

    /// The cameras' models.
    pub fn cameras(&self) -> impl Iterator<Item = &Camera> {
        self.cameras.iter().map(|c| &c.camera)
    }

    /// The next frame's stamp: its sequence number and capture time (the
    /// simulated clock, or `wall_ns` when the run keeps the wall's time).
    pub fn next_stamp(&self, wall_ns: Option<u64>) -> Stamp {
        Stamp::new(
            self.frame_seq + 1,
            wall_ns.unwrap_or_else(|| capture_time_ns(self.episode.time_s)),
        )
    }

    /// Senses the next frame (stamped `stamp`, from [`Self::next_stamp`]):
    /// the pose, the near-field costmap, then per camera its model, depth,
    /// the oracle's navigability (with `oracle`) and the image last, so a
    /// stage woken by the image finds the rest there. Only the topics
    /// `wanted` are made (a camera none of whose topics is wanted is not
    /// rendered): the benchmark's map-only methods cost no rendering, and
    /// an RGB-only graph no depth.
    pub fn sense(&mut self, stamp: Stamp, wanted: impl Fn(&str) -> bool) -> Vec<(String, Message)> {
        self.frame_seq = stamp.frame_seq;
        let r = self.episode.robot;
        let [px, py, pyaw] = reported_pose(
            r.pose(),
            self.options.pose_noise_m,
            self.options.yaw_noise_deg.to_radians(),
            &mut self.noise,
        );
        // Height is the ground under the robot (the camera rides on it), so
        // recorded trajectories project into past frames on hills too.
        let world = &self.episode.scenario.world;
        let (cx, cy) = world.cell_of(r.x_m, r.y_m);
        let pose = Pose {
            stamp,
            position_m: [px, py, world.ground_m(cx, cy) as f64],
            yaw_rad: pyaw,
            linear_mps: r.linear_mps as f32,
            angular_radps: r.angular_radps as f32,
            ..Default::default()
        };
        let (lh, lc) = self.sensor.observe(world, r.x_m, r.y_m, stamp);
        let mut out = vec![
            (topics::pose().name().to_string(), Message::Pose(pose)),
            (
                topics::costmap("local").name().to_string(),
                Message::Costmap(Sliced {
                    header: lh,
                    data: lc,
                }),
            ),
        ];
        if self.options.far_field_oracle {
            let g = PolarGeometry::fitam_default();
            let header = PolarBinsHeader {
                stamp,
                heading_bins: g.heading_bins as u32,
                first_heading_start_rad: g.first_heading_start_rad as f32,
                heading_width_rad: g.heading_width_rad as f32,
                range_edges_m: FixedVec::from_slice(
                    &g.range_edges_m
                        .iter()
                        .map(|&e| e as f32)
                        .collect::<Vec<_>>(),
                )
                .unwrap_or_default(),
            };
            let data = ground_truth_bins(world, &g, r.pose(), &LabelRules::default());
            out.push((
                topics::polar_bins().name().to_string(),
                Message::PolarBins(Sliced { header, data }),
            ));
        }
        for cam in &mut self.cameras {
            let [info, depth, navigability, image] = cam.topics.clone();
            let channels = Channels {
                rgb: wanted(&image),
                depth: wanted(&depth),
                class_ids: self.options.oracle && wanted(&navigability),
            };
            let rendered = channels.rgb || channels.depth || channels.class_ids;
            if !(rendered || wanted(&info)) {
                continue;
            }
            let (w, h) = (cam.camera.model.width, cam.camera.model.height);
            let id = cam.camera.id;
            if rendered {
                cam.renderer
                    .render_channels(world, r.pose(), &mut cam.frame, channels);
            }
            let f = &cam.frame;
            out.push((info, Message::CameraInfo(cam.camera.to_info(stamp))));
            if channels.depth {
                let mut data = Vec::with_capacity(f.depth_m.len() * 4);
                for d in &f.depth_m {
                    data.extend_from_slice(&d.to_le_bytes());
                }
                let depth_m = Image {
                    header: ImageHeader::packed(stamp, id, w, h, PixelEncoding::F32),
                    data,
                };
                out.push((depth, Message::Image(depth_m)));
            }
            if channels.class_ids {
                let nav = Image {
                    header: ImageHeader::packed(stamp, id, w, h, PixelEncoding::MONO8),
                    data: f
                        .class_ids
                        .iter()
                        .map(|&c| if navigable_class(c) { 255 } else { 0 })
                        .collect(),
                };
                out.push((navigability, Message::Image(nav)));
            }
            if channels.rgb {
                let rgb = Image {
                    header: ImageHeader::packed(stamp, id, w, h, PixelEncoding::RGB8),
                    data: f.rgb.clone(),
                };
                out.push((image, Message::Image(rgb)));
            }
        }
        out
    }

    /// Drives one frame period: the base obeys `command` (if one came, and
    /// it is finite) for its time-to-live, then stops. Returns whether the
    /// command was usable (a late or non-finite one is not) and the outcome.
    pub fn drive(&mut self, command: Option<VelocityCommand>) -> (bool, Outcome) {
        let fresh =
            command.is_some_and(|c| c.linear_mps.is_finite() && c.angular_radps.is_finite());
        if let Some(c) = command {
            self.base.receive(c, self.episode.time_s);
        }
        let v_w = self.base.command(self.episode.time_s);
        let dt = self.dt_s();
        (fresh, self.episode.step(v_w, dt))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topics_of(sensed: &[(String, Message)]) -> Vec<&str> {
        sensed.iter().map(|(t, _)| t.as_str()).collect()
    }

    #[test]
    fn only_the_wanted_topics_are_made_and_the_image_is_the_same_either_way() {
        let options = SimOptions {
            oracle: true,
            width: 64,
            height: 36,
            ..Default::default()
        };
        let mut sim = SimRobot::new(&options).unwrap();
        let stamp = sim.next_stamp(None);
        let all = sim.sense(stamp, |_| true);
        let names = topics_of(&all);
        let image = *names.iter().find(|t| t.ends_with("/image")).unwrap();
        let depth = *names.iter().find(|t| t.ends_with("/depth")).unwrap();
        let nav = *names.iter().find(|t| t.ends_with("/navigability")).unwrap();
        let info = *names.iter().find(|t| t.ends_with("/info")).unwrap();
        assert_eq!(names.last(), Some(&image), "the image comes last");

        let only_image = sim.sense(stamp, |t| t == image);
        let got = topics_of(&only_image);
        assert!(got.contains(&image) && got.contains(&info), "{got:?}");
        assert!(!got.contains(&depth) && !got.contains(&nav), "{got:?}");
        let pixels = |sensed: &[(String, Message)]| match &sensed.last().unwrap().1 {
            Message::Image(i) => i.data.clone(),
            m => panic!("{m:?}"),
        };
        assert_eq!(pixels(&only_image), pixels(&all));

        let only_nav = topics_of(&sim.sense(stamp, |t| t == nav)).join(" ");
        assert!(
            only_nav.contains(nav) && !only_nav.contains(image),
            "{only_nav}"
        );
        let camera_topics = [image, depth, nav, info];
        let map_only = sim.sense(stamp, |t| !camera_topics.contains(&t));
        let got = topics_of(&map_only);
        assert!(got.iter().all(|t| !camera_topics.contains(t)), "{got:?}");
        assert!(got.len() >= 2, "pose and near field still: {got:?}");
    }
}
