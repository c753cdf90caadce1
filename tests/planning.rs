//! FITAM's claim on a constructed world (Fig. 1): a road 60 m to the side of
//! the straight line to the goal, behind forest. Near-field sensing alone
//! (25 m) never sees it, so the "no far-field" baseline ploughs through the
//! forest; with ground-truth far-field observations the planner finds the
//! road and the drive costs less.
//!
//! The loop is FITAM's sense-plan-act evaluation: far-field observe + Kalman
//! update, fix the near-field cells, repair D* Lite with the changed cells,
//! drive along the path until 10 m travelled or the next cell was not seen
//! by near-field sensing, repeat. Library code only: the fused map of
//! `farsight-costmap-fusion` and the D* Lite of `farsight-subgoal-selection`.

use farsight_costmap_fusion::kalman::FarFieldConfig;
use farsight_costmap_fusion::map::FusionMap;
use farsight_costmap_fusion::swath::{for_each_swath_cell, PolarGeometry};
use farsight_interfaces::msg::PolarCell;
use farsight_subgoal_selection::dstar_lite::{CostGrid, DStarLite};

/// FITAM's speed classes: 0.5, 2.25, 4.25 m/s.
const CLASS_COST: [f32; 3] = [2.0, 1.0 / 2.25, 1.0 / 4.25];
const FOREST: u8 = 0;
const ROAD: u8 = 2;
const SIZE: usize = 240;
const NEAR_RANGE_M: f64 = 25.0;

/// The world: forest, with a road north-south 60 m east of the start and a
/// road west to the goal along its row.
fn road_forest() -> Vec<u8> {
    let mut w = vec![FOREST; SIZE * SIZE];
    for y in 0..SIZE {
        for x in 178..=182 {
            w[y * SIZE + x] = ROAD;
        }
    }
    for y in 218..=222 {
        for x in 120..=182 {
            w[y * SIZE + x] = ROAD;
        }
    }
    w
}

fn class_at(world: &[u8], x: i64, y: i64) -> Option<u8> {
    (x >= 0 && y >= 0 && (x as usize) < SIZE && (y as usize) < SIZE)
        .then(|| world[y as usize * SIZE + x as usize])
}

/// Ground-truth far-field labels (FITAM section IV-B): per swath, the
/// cheapest class covering at least rho_class = 0.2 of it.
fn ground_truth_bins(world: &[u8], g: &PolarGeometry, x: f64, y: f64, yaw: f64) -> Vec<PolarCell> {
    let radial = g.radial_bins();
    let mut counts = vec![[0usize; 3]; g.heading_bins * radial];
    for_each_swath_cell(g, x, y, yaw, 1.0, |gx, gy, h, r| {
        if let Some(c) = class_at(world, gx, gy) {
            counts[h * radial + r][c as usize] += 1;
        }
    });
    counts
        .iter()
        .map(|n| {
            let total: usize = n.iter().sum();
            let mut by_cost: Vec<usize> = (0..3).collect();
            by_cost.sort_by(|&a, &b| CLASS_COST[a].total_cmp(&CLASS_COST[b]));
            match by_cost
                .into_iter()
                .find(|&c| total > 0 && n[c] * 5 >= total)
            {
                Some(c) => PolarCell {
                    cost_s_per_m: CLASS_COST[c],
                    variance: 0.1,
                    class_id: c as u32,
                    probability: 0.9,
                },
                None => PolarCell::NO_MEASUREMENT,
            }
        })
        .collect()
}

struct Drive {
    reached: bool,
    cost_s: f64,
    road_cells: usize,
    cells: usize,
}

fn drive(world: &[u8], use_far_field: bool) -> Drive {
    let geometry = PolarGeometry::fitam_default();
    let cfg = FarFieldConfig::default();
    let mut map = FusionMap::new(201, 201, 1.0, cfg);
    let (mut pos, goal) = ((120usize, 20usize), (120usize, 220usize));
    let mut planner = DStarLite::new(
        CostGrid::new(SIZE, SIZE, 1.0, cfg.unknown_cost_s_per_m),
        pos,
        goal,
        CLASS_COST[2] as f64,
    );
    let mut yaw = std::f64::consts::FRAC_PI_2;
    let mut out = Drive {
        reached: false,
        cost_s: 0.0,
        road_cells: 0,
        cells: 0,
    };
    for _ in 0..200 {
        let (x, y) = (pos.0 as f64, pos.1 as f64);
        map.recenter(x, y);
        if use_far_field {
            map.observe_far_field(
                &geometry,
                &ground_truth_bins(world, &geometry, x, y, yaw),
                x,
                y,
                yaw,
            );
            map.add_process_noise();
        }
        let n = NEAR_RANGE_M as i64;
        for dy in -n..=n {
            for dx in -n..=n {
                if ((dx * dx + dy * dy) as f64).sqrt() <= NEAR_RANGE_M {
                    let (gx, gy) = (pos.0 as i64 + dx, pos.1 as i64 + dy);
                    if let Some(c) = class_at(world, gx, gy) {
                        map.fix_local(gx, gy, CLASS_COST[c as usize]);
                    }
                }
            }
        }
        // Hand D* Lite only the cells whose planning cost changed.
        for gy in 0..SIZE {
            for gx in 0..SIZE {
                let c = map
                    .planning_cost(gx as i64, gy as i64, use_far_field)
                    .unwrap_or(cfg.unknown_cost_s_per_m);
                planner.set_cost(gx, gy, c);
            }
        }
        planner.compute().expect("a path exists");
        let path = planner.path();
        let mut travelled = 0.0;
        for w in path.windows(2) {
            let next = w[1];
            if map.local_cost(next.0 as i64, next.1 as i64).is_none() || travelled >= 10.0 {
                break;
            }
            let step = ((w[0].0.abs_diff(next.0) + w[0].1.abs_diff(next.1)) as f64).min(2.0);
            let len = if step > 1.0 {
                std::f64::consts::SQRT_2
            } else {
                1.0
            };
            let class = class_at(world, next.0 as i64, next.1 as i64).unwrap();
            out.cost_s += CLASS_COST[class as usize] as f64 * len;
            out.road_cells += (class == ROAD) as usize;
            out.cells += 1;
            travelled += len;
            yaw = (next.1 as f64 - pos.1 as f64).atan2(next.0 as f64 - pos.0 as f64);
            pos = next;
        }
        planner.move_start(pos);
        if pos == goal {
            out.reached = true;
            break;
        }
    }
    out
}

#[test]
fn far_field_finds_the_road_behind_the_forest() {
    let world = road_forest();
    let base = drive(&world, false);
    let fitam = drive(&world, true);
    eprintln!(
        "no far-field: {:.0} s over {} cells ({} road); far-field: {:.0} s over {} cells ({} road)",
        base.cost_s, base.cells, base.road_cells, fitam.cost_s, fitam.cells, fitam.road_cells
    );
    assert!(base.reached && fitam.reached);
    assert!(
        fitam.road_cells * 2 > fitam.cells,
        "the far-field route mostly uses the road: {} of {} cells",
        fitam.road_cells,
        fitam.cells
    );
    assert!(
        fitam.cost_s < 0.8 * base.cost_s,
        "far-field {:.0} s vs no far-field {:.0} s",
        fitam.cost_s,
        base.cost_s
    );
}

/// The planning graph as processes: costmap-fusion fixes a wall from a
/// near-field costmap (as a lidar stack or the simulator would publish),
/// subgoal-selection plans around it with D* Lite, and velocity-servoing
/// tracks the planned path by carrot.
mod graph {
    use farsight_interfaces::msg::*;
    use farsight_interfaces::topics;
    use farsight_tests::Namespace;
    use std::time::{Duration, Instant};

    /// A near-field costmap of (2 half + 1) m square around the origin: free
    /// ground at 0.5 s/m, lethal where `lethal(x, y)` (whole metres).
    fn near_field(half: i64, lethal: impl Fn(i64, i64) -> bool) -> (CostmapHeader, Vec<CostCell>) {
        let side = 2 * half + 1;
        let header = CostmapHeader {
            stamp: farsight_tests::stamp_now(1),
            layer: CostmapLayer::LOCAL,
            width: side as u32,
            height: side as u32,
            resolution_m: 1.0,
            x_min_m: -half as f64,
            y_max_m: half as f64,
        };
        let cells = (0..side * side)
            .map(|k| CostCell {
                cost_s_per_m: if lethal(-half + k % side, half - k / side) {
                    f32::INFINITY
                } else {
                    0.5
                },
                variance: 0.0,
            })
            .collect();
        (header, cells)
    }

    /// A costmap header stamped now: a near-field sensor's map as it goes out.
    fn restamped(header: CostmapHeader) -> CostmapHeader {
        CostmapHeader {
            stamp: farsight_tests::stamp_now(header.stamp.frame_seq),
            ..header
        }
    }

    /// Localisation and the operator, as the planners see them: the robot at
    /// the origin facing east, the goal 20 m ahead.
    fn robot_at_origin_goal_ahead(
        pose: &farsight_interfaces::transport::ipc::Publisher<Pose>,
        goal: &farsight_interfaces::transport::ipc::Publisher<NavGoal>,
    ) {
        pose.publish(&farsight_tests::pose_now()).unwrap();
        goal.publish(&NavGoal {
            kind: GoalKind::LOCAL,
            x_m: 20.0,
            tolerance_m: 1.0,
            ..Default::default()
        })
        .unwrap();
    }

    #[test]
    fn a_wall_seen_by_near_field_sensing_is_planned_around_and_driven() {
        let ns = Namespace::new("planning");
        let bus = ns.bus("planning-test");
        let fusion_cfg = ns.write(
            "costmap-fusion.toml",
            "width_cells = 61\nheight_cells = 61\npublish_rate_hz = 5.0\n",
        );
        let planner_cfg = ns.write(
            "subgoal-selection.toml",
            "method = \"dstar_lite\"\nsubgoal_distance_m = 5.0\n[planner]\nmargin_m = 15.0\n",
        );
        let servo_cfg = ns.write("velocity-servoing.toml", "track = \"path\"\n");
        let fused = bus.slice_subscriber(&topics::costmap("fused")).unwrap();
        let planned = bus.subscriber(&topics::path("planned")).unwrap();
        let cmds = bus.subscriber(&topics::velocity_command()).unwrap();
        let pose = bus.publisher(&topics::pose()).unwrap();
        let goal = bus.publisher(&topics::goal()).unwrap();
        let local = bus
            .slice_publisher(&topics::costmap("local"), 21 * 21)
            .unwrap();
        let _graph = ns.run_graph(
            &[
                ("costmap-fusion", &fusion_cfg),
                ("subgoal-selection", &planner_cfg),
                ("velocity-servoing", &servo_cfg),
            ],
            &["state/pose", "nav/goal", "costmap/local"],
            &["cmd/velocity"],
        );

        // Near-field map 21x21 m around the robot at the origin: free ground
        // (0.5 s/m) with a lethal wall at x = 8 m, y in -6..=6 m.
        let (header, cells) = near_field(10, |x, y| x == 8 && y.abs() <= 6);
        let end = Instant::now() + Duration::from_secs(20);
        let mut around = None;
        while Instant::now() < end && around.is_none() {
            robot_at_origin_goal_ahead(&pose, &goal);
            local.publish_copy(restamped(header), &cells).unwrap();
            if let Some(p) = planned.latest().unwrap() {
                let pts = p.points.as_slice();
                // Around the wall: some point beyond |y| = 6 before x = 8.
                if p.frame == PathFrame::WORLD
                    && pts.iter().any(|q| q[1].abs() > 6.5 && q[0] <= 9.0)
                {
                    around = Some(p);
                }
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let p = around.unwrap_or_else(|| {
            panic!(
                "no path around the wall; last {:?}\nfusion:\n{}\nplanner:\n{}",
                planned
                    .latest()
                    .unwrap()
                    .map(|p| p.points.as_slice().to_vec()),
                ns.node_log("costmap-fusion"),
                ns.node_log("subgoal-selection")
            )
        });
        let pts = p.points.as_slice();
        assert!(
            pts.iter()
                .all(|q| !((q[0] - 8.0).abs() < 0.5 && q[1].abs() <= 6.5)),
            "never through the wall: {pts:?}"
        );
        let last = pts.last().unwrap();
        assert!(
            (last[0] - 20.0).abs() < 1e-3 && last[1].abs() < 1e-3,
            "ends at the goal: {last:?}"
        );
        // The fused map holds the wall as lethal at (8, 0).
        let f = fused.latest().unwrap().expect("a fused costmap");
        let h = *f.header();
        let k = h.cell_index(8.0, 0.0).expect("inside the map");
        assert!(f.data()[k].cost_s_per_m.is_infinite());
        // The servo follows the path: forward and turning toward the detour.
        let end = Instant::now() + Duration::from_secs(10);
        loop {
            pose.publish(&farsight_tests::pose_now()).unwrap();
            if let Some(c) = cmds.latest().unwrap() {
                if c.reason == CommandReason::TRACKING
                    && c.linear_mps > 0.0
                    && c.angular_radps.abs() > 0.05
                {
                    break;
                }
            }
            assert!(
                Instant::now() < end,
                "servo never tracked the path: {:?}\n{}",
                cmds.latest(),
                ns.node_log("velocity-servoing")
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    #[test]
    fn far_field_ensemble_outputs_become_far_field_cells_in_the_fused_map() {
        use farsight_interfaces::camera::{Camera, CameraModel, Mount};
        let ns = Namespace::new("fitamchain");
        let bus = ns.bus("fitam-test");
        let bins_cfg = ns.write(
            "bin-projection.toml",
            "method = \"fitam\"\ncameras = [\"front\"]\n",
        );
        let fusion_cfg = ns.write(
            "costmap-fusion.toml",
            "width_cells = 241\nheight_cells = 241\npublish_rate_hz = 5.0\nlocal_costmaps = []\n",
        );
        let fused = bus.slice_subscriber(&topics::costmap("fused")).unwrap();
        let polar = bus.slice_subscriber(&topics::polar_bins()).unwrap();
        let _graph = ns.run_graph(
            &[
                ("bin-projection", &bins_cfg),
                ("costmap-fusion", &fusion_cfg),
            ],
            &[
                "state/pose",
                "camera/front/info",
                "perception/front/far_field",
            ],
            &["costmap/fused"],
        );
        let pose = bus.publisher(&topics::pose()).unwrap();
        let info = bus.publisher(&topics::camera_info("front")).unwrap();
        let tensor = bus
            .slice_publisher(&topics::far_field_logits("front"), 8 * 3 * 2 * 3)
            .unwrap();
        // A 90 degree camera facing ahead (the robot faces north), cut in 8
        // slices of 11.25 degrees, one per heading bin it sees; every
        // member of every radial bin says class 2 (4.25 m/s, 0.235 s/m).
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(64, 32, 32.0, 32.0, 31.5, 15.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
        );
        let robot = Pose {
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..Default::default()
        };
        let logits: Vec<f32> = (0..8 * 3 * 2).flat_map(|_| [0.0, 0.0, 8.0]).collect();
        let end = Instant::now() + Duration::from_secs(20);
        let mut seq = 0;
        loop {
            seq += 1;
            pose.publish(&Pose {
                stamp: farsight_tests::stamp_now(seq),
                ..robot
            })
            .unwrap();
            info.publish(&cam.to_info(farsight_tests::stamp_now(seq)))
                .unwrap();
            tensor
                .publish_copy(
                    TensorHeader::new(farsight_tests::stamp_now(seq), 0, &[8, 3, 2, 3]),
                    &logits,
                )
                .unwrap();
            std::thread::sleep(Duration::from_millis(50));
            if let (Some(p), Some(f)) = (polar.latest().unwrap(), fused.latest().unwrap()) {
                let h = *f.header();
                let at = |x: f64, y: f64| f.data()[h.cell_index(x, y).expect("inside the map")];
                let (ahead, behind) = (at(0.0, 60.0), at(0.0, -60.0));
                if f.header().stamp.frame_seq > 0 && (ahead.cost_s_per_m - 1.0 / 4.25).abs() < 0.01
                {
                    assert_eq!(p.header().heading_bins, 32);
                    assert_eq!(behind.cost_s_per_m, 1.0, "nobody looked behind: unknown");
                    assert!(ahead.variance < 0.05, "{ahead:?}");
                    let too_far = at(0.0, 110.0);
                    assert_eq!(too_far.cost_s_per_m, 1.0, "beyond the last radial edge");
                    break;
                }
            }
            assert!(
                Instant::now() < end,
                "the far-field layer never showed the road ahead\n{}",
                ns.node_log("costmap-fusion")
            );
        }
    }

    #[test]
    fn hip_builds_its_library_from_poses_and_steers_off_a_lethal_trajectory() {
        let ns = Namespace::new("hipgraph");
        let bus = ns.bus("hip-test");
        // Recorded driving at 2 m/s, 10 Hz: straight, hard left, hard right
        // in turn, 6 s each, twice over.
        let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
        let mut csv = String::from("t_s,x_m,y_m,yaw_rad\n");
        for k in 0..360 {
            let t = k as f64 * 0.1;
            csv += &format!("{t},{x},{y},{yaw}\n");
            let w = [0.0, 1.0, -1.0][(k / 60) % 3];
            x += 0.2 * yaw.cos();
            y += 0.2 * yaw.sin();
            yaw += 0.1 * w;
        }
        let poses = ns.write("poses.csv", &csv);
        let library = poses.with_file_name("hip-library.toml");
        let out = std::process::Command::new(farsight_tests::bin("farsight"))
            .args([
                "hip-library",
                poses.to_str().unwrap(),
                "--k",
                "3",
                "--out",
                library.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(String::from_utf8_lossy(&out.stdout).contains("wrote 3 trajectories"));

        let fusion_cfg = ns.write(
            "costmap-fusion.toml",
            "width_cells = 41\nheight_cells = 41\npublish_rate_hz = 10.0\n",
        );
        let planner_cfg = ns.write(
            "subgoal-selection.toml",
            "method = \"hip\"\nhip_library = \"hip-library.toml\"\nreplan_rate_hz = 10.0\n",
        );
        let planned = bus.subscriber(&topics::path("planned")).unwrap();
        let subgoals = bus.subscriber(&topics::subgoal()).unwrap();
        let pose = bus.publisher(&topics::pose()).unwrap();
        let goal = bus.publisher(&topics::goal()).unwrap();
        let local = bus
            .slice_publisher(&topics::costmap("local"), 11 * 11)
            .unwrap();
        let _graph = ns.run_graph(
            &[
                ("costmap-fusion", &fusion_cfg),
                ("subgoal-selection", &planner_cfg),
            ],
            &["state/pose", "nav/goal", "costmap/local"],
            &["nav/subgoal"],
        );
        // Free ground, optionally with a rock 3 m ahead across |y| <= 1.
        let ground = |rock: bool| near_field(5, |x, y| rock && x == 3 && y.abs() <= 1);
        let wait_path = |rock: bool, want: &dyn Fn(&[[f32; 2]]) -> bool| {
            let end = Instant::now() + Duration::from_secs(15);
            while Instant::now() < end {
                robot_at_origin_goal_ahead(&pose, &goal);
                let (header, cells) = ground(rock);
                local.publish_copy(restamped(header), &cells).unwrap();
                if let Some(p) = planned.latest().unwrap() {
                    if want(p.points.as_slice()) {
                        return p;
                    }
                }
                std::thread::sleep(Duration::from_millis(50));
            }
            panic!(
                "HIP never chose the expected trajectory (rock {rock}); last {:?}\n{}",
                planned
                    .latest()
                    .unwrap()
                    .map(|p| p.points.as_slice().to_vec()),
                ns.node_log("subgoal-selection")
            );
        };
        // Open ground: the straight trajectory ends in the goal region.
        let straight = wait_path(false, &|pts| {
            pts.len() == 11 && pts.iter().all(|q| q[1].abs() < 0.3)
        });
        assert!(straight.points.as_slice().last().unwrap()[0] > 3.0);
        assert_eq!(
            subgoals.latest().unwrap().unwrap().source,
            SubgoalSource::HIP
        );
        // The rock makes straight lethal: an arc that never enters it.
        let arc = wait_path(true, &|pts| pts.iter().any(|q| q[1].abs() > 1.0));
        for q in arc.points.as_slice() {
            assert!(
                !((q[0] - 3.0).abs() <= 0.5 && q[1].abs() <= 1.5),
                "through the rock: {q:?}"
            );
        }
    }

    #[test]
    fn a_depth_camera_fixes_near_field_cells_lethal_or_free() {
        use farsight_interfaces::camera::{Camera, CameraModel, Mount};
        let ns = Namespace::new("depthnear");
        let bus = ns.bus("depth-test");
        let cfg = ns.write(
            "costmap-fusion.toml",
            "width_cells = 41\nheight_cells = 41\npublish_rate_hz = 10.0\nlocal_costmaps = []\n[near_field]\ndepth_cameras = [\"front\"]\npixel_stride = 1\n",
        );
        let fused = bus.slice_subscriber(&topics::costmap("fused")).unwrap();
        let fusion = ns.start_stage("farsight-costmap-fusion", "costmap-fusion", &cfg);
        let pose = bus.publisher(&topics::pose()).unwrap();
        let info = bus.publisher(&topics::camera_info("front")).unwrap();
        let depth = bus
            .slice_publisher(&topics::depth("front"), 80 * 60 * 4)
            .unwrap();
        // Level camera 1 m up; flat ground and a 1.5 m box 5..6 m ahead, |y| < 0.5.
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(80, 60, 40.0, 40.0, 39.5, 29.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
        );
        let values: Vec<f32> = (0..80 * 60)
            .map(|i| {
                let (u, v) = ((i % 80) as f64, (i / 80) as f64);
                let optical = cam.model.unproject(u, v);
                let r = cam.mount.robot_from_optical * optical;
                let t_box = 5.0 / r.x;
                let z_box = 1.0 + r.z * t_box;
                let t = if r.x > 0.0 && (r.y * t_box).abs() < 0.5 && (0.0..1.5).contains(&z_box) {
                    t_box
                } else if r.z < -1e-6 {
                    1.0 / -r.z
                } else {
                    return f32::INFINITY;
                };
                (t * optical.z) as f32 // depth along the optical axis
            })
            .collect();
        let end = Instant::now() + Duration::from_secs(15);
        loop {
            pose.publish(&farsight_tests::pose_now()).unwrap();
            info.publish(&cam.to_info(farsight_tests::stamp_now(1)))
                .unwrap();
            depth
                .publish_copy(
                    ImageHeader::packed(
                        farsight_tests::stamp_now(1),
                        0,
                        80,
                        60,
                        PixelEncoding::F32,
                    ),
                    bytemuck::cast_slice(&values),
                )
                .unwrap();
            std::thread::sleep(Duration::from_millis(50));
            if let Some(f) = fused.latest().unwrap() {
                let h = *f.header();
                let at = |x: f64, y: f64| f.data()[h.cell_index(x, y).expect("inside the map")];
                if at(5.0, 0.0).cost_s_per_m.is_infinite() {
                    assert_eq!(at(3.0, 0.0).cost_s_per_m, 0.5, "ground ahead is free");
                    assert_eq!(at(3.0, 0.0).variance, 0.0, "fixed by near-field");
                    assert_eq!(at(-3.0, 0.0).cost_s_per_m, 1.0, "behind: unseen, unknown");
                    break;
                }
            }
            assert!(
                Instant::now() < end,
                "the box never became lethal\n{}",
                fusion.stderr_so_far()
            );
        }
    }

    /// A HIP library (straight, which ends in the goal region of a goal
    /// ahead; left and right, which miss it) and a test ONNX model for it
    /// (written by the test support, no training) whose log q depends on
    /// the image's mean colour: green frames favour left, red ones
    /// straight. The model's config is `hip-model.toml`.
    fn write_hip_library_and_colour_model(ns: &Namespace) {
        let line = |dx: f64, dy: f64| {
            (1..=10)
                .map(|i| format!("[{}, {}]", dx * i as f64, dy * i as f64))
                .collect::<Vec<_>>()
                .join(", ")
        };
        ns.write(
            "hip-library.toml",
            &format!(
                "step_s = 0.2\ntrajectories = [[{}], [{}], [{}]]\n",
                line(0.4, 0.0),
                line(0.3, 0.25),
                line(0.3, -0.25)
            ),
        );
        // log q = w . mean colour.
        let model = farsight_tests::onnx_fixture::mean_colour_linear(
            8,
            8,
            &[
                [0.0, -1000.0, 0.0],
                [-1000.0, 0.0, 0.0],
                [-1000.0, -1000.0, 0.0],
            ],
        );
        std::fs::write(ns.write("hip.onnx", "").as_path(), model).unwrap();
        ns.write("hip-model.toml", &hip_model_config(3));
    }

    fn hip_model_config(classes: usize) -> String {
        format!("model = \"hip.onnx\"\n[input]\nname = \"image\"\nlayout = \"nchw\"\nwidth = 8\nheight = 8\nresize = \"bilinear\"\ncolor = \"rgb\"\nscale = 0.00392156862745098\n[[outputs]]\nname = \"out\"\nkind = \"trajectory_log_likelihood\"\nclasses = {classes}\n")
    }

    /// The subgoal stage running HIP with the colour model, and the test's
    /// ends of its topics.
    struct HipRig {
        planned: farsight_interfaces::transport::ipc::Subscriber<farsight_interfaces::msg::Path>,
        health: farsight_interfaces::transport::ipc::Subscriber<StageHealth>,
        planner: farsight_tests::Proc,
        pose: farsight_interfaces::transport::ipc::Publisher<Pose>,
        goal: farsight_interfaces::transport::ipc::Publisher<NavGoal>,
        fused: farsight_interfaces::transport::ipc::SlicePublisher<CostmapHeader, CostCell>,
        image: farsight_interfaces::transport::ipc::SlicePublisher<ImageHeader, u8>,
    }

    impl HipRig {
        fn start(
            ns: &Namespace,
            bus: &farsight_interfaces::transport::ipc::Bus,
            hip: &str,
        ) -> Self {
            write_hip_library_and_colour_model(ns);
            let cfg = ns.write(
                "subgoal-selection.toml",
                &format!("method = \"hip\"\nhip_library = \"hip-library.toml\"\nhip_model = \"hip-model.toml\"\nreplan_rate_hz = 20.0\n{hip}"),
            );
            Self {
                planned: bus.subscriber(&topics::path("planned")).unwrap(),
                health: bus
                    .subscriber(&topics::health("subgoal-selection"))
                    .unwrap(),
                planner: ns.start_stage("farsight-subgoal-selection", "subgoal-selection", &cfg),
                pose: bus.publisher(&topics::pose()).unwrap(),
                goal: bus.publisher(&topics::goal()).unwrap(),
                fused: bus
                    .slice_publisher(&topics::costmap("fused"), 11 * 11)
                    .unwrap(),
                image: bus
                    .slice_publisher(&topics::camera_image("front"), 16 * 16 * 3)
                    .unwrap(),
            }
        }

        /// Feeds the pose, the goal, `cells` and (if `rgb`) a plain camera
        /// frame until the planned path's last point satisfies `want_y`.
        fn choose_with(
            &self,
            cells: &(CostmapHeader, Vec<CostCell>),
            rgb: [u8; 3],
            want_y: &dyn Fn(f32) -> bool,
        ) {
            let pixels: Vec<u8> = (0..16 * 16).flat_map(|_| rgb).collect();
            let end = Instant::now() + Duration::from_secs(15);
            loop {
                robot_at_origin_goal_ahead(&self.pose, &self.goal);
                self.fused
                    .publish_copy(restamped(cells.0), &cells.1)
                    .unwrap();
                self.image
                    .publish_copy(
                        ImageHeader::packed(
                            farsight_tests::stamp_now(1),
                            0,
                            16,
                            16,
                            PixelEncoding::RGB8,
                        ),
                        &pixels,
                    )
                    .unwrap();
                std::thread::sleep(Duration::from_millis(50));
                if let Some(p) = self.planned.latest().unwrap() {
                    if p.points.as_slice().last().is_some_and(|q| want_y(q[1])) {
                        return;
                    }
                }
                assert!(
                    Instant::now() < end,
                    "no HIP choice for {rgb:?}; last {:?}\n{}",
                    self.planned
                        .latest()
                        .unwrap()
                        .map(|p| p.points.as_slice().to_vec()),
                    self.planner.stderr_so_far()
                );
            }
        }
    }

    /// HIP with a learned model: the same library and costmap give a
    /// different choice for a green and a red camera frame, through ONNX
    /// Runtime in the subgoal stage.
    #[test]
    fn hip_learned_term_comes_from_an_onnx_model_on_the_camera_frame() {
        let ns = Namespace::new("hiponnx");
        let bus = ns.bus("hip-onnx-test");
        let rig = HipRig::start(&ns, &bus, "");
        let open = near_field(5, |_, _| false);
        rig.choose_with(&open, [0, 255, 0], &|y| y > 2.0); // green: left
        rig.choose_with(&open, [255, 0, 0], &|y| y.abs() < 0.1); // red: straight

        // A model scoring a different number of trajectories than the
        // library holds is refused at start, naming both.
        ns.write("hip-model-4.toml", &hip_model_config(4));
        let bad = ns.write(
            "subgoal-selection-bad.toml",
            "method = \"hip\"\nhip_library = \"hip-library.toml\"\nhip_model = \"hip-model-4.toml\"\n",
        );
        let err = ns.start_must_fail("farsight-subgoal-selection", &bad);
        assert!(
            err.contains("scores 4 trajectories but the HIP library holds 3"),
            "{err}"
        );
    }

    /// phi = 0 is HIP's Learner alone (section V): the costmap takes no
    /// part, so a red frame (straight is likeliest) sends the robot
    /// straight at a wall the hybrid steers round; and with no fresh frame
    /// it plans nothing rather than follow the directive blind: each map is
    /// answered with an empty path, on which the servo stops.
    #[test]
    fn hips_learner_alone_ignores_the_costmap_and_needs_a_fresh_frame() {
        let wall_ahead = near_field(5, |x, y| x == 3 && y.abs() <= 1);
        let ns = Namespace::new("hiplearner");
        let bus = ns.bus("hip-learner-test");
        let hybrid = HipRig::start(&ns, &bus, "[hip]\nphi = 0.75\n");
        hybrid.choose_with(&wall_ahead, [255, 0, 0], &|y| y.abs() > 2.0);
        drop(hybrid);
        let ns = Namespace::new("hiplearner0");
        let bus = ns.bus("hip-learner-test");
        let learner = HipRig::start(&ns, &bus, "[hip]\nphi = 0.0\n");
        learner.choose_with(&wall_ahead, [255, 0, 0], &|y| y.abs() < 0.1);
        // Reports from before the first frame (no term yet) are not the
        // staleness this waits for.
        learner.health.latest().unwrap();
        let send_map = || {
            robot_at_origin_goal_ahead(&learner.pose, &learner.goal);
            learner
                .fused
                .publish_copy(restamped(wall_ahead.0), &wall_ahead.1)
                .unwrap();
            std::thread::sleep(Duration::from_millis(50));
        };
        // Frames stop: within the input deadline (1 s) the term goes stale,
        // and the Learner says so.
        let end = Instant::now() + Duration::from_secs(15);
        loop {
            send_map();
            let h = learner.health.latest().unwrap();
            if h.as_ref()
                .is_some_and(|h| h.reason.as_str().contains("no fresh learned term"))
            {
                // Drain what was planned before.
                learner.planned.latest().unwrap();
                break;
            }
            assert!(
                Instant::now() < end,
                "the Learner never said its term was stale: {h:?}\n{}",
                learner.planner.stderr_so_far()
            );
        }
        // Then it plans nothing more: ten maps, and more until one is
        // answered (an empty path, however slow the machine).
        let (mut planned_after, mut empty_after) = (0, 0);
        let end = Instant::now() + Duration::from_secs(15);
        for k in 0.. {
            if k >= 10 && (empty_after > 0 || Instant::now() >= end) {
                break;
            }
            send_map();
            match learner.planned.latest().unwrap() {
                Some(p) if p.points.is_empty() => empty_after += 1,
                Some(_) => planned_after += 1,
                None => {}
            }
        }
        assert_eq!(planned_after, 0, "plans without a fresh frame");
        assert!(empty_after > 0, "the maps went unanswered");
    }

    /// costmap-fusion as a process, with the test's ends of its topics:
    /// `costmap/local` 21x21 cells, `bins/polar` 32 x 3 bins.
    struct FusionRig {
        fused: farsight_interfaces::transport::ipc::SliceSubscriber<CostmapHeader, CostCell>,
        health: farsight_interfaces::transport::ipc::Subscriber<StageHealth>,
        fusion: farsight_tests::Proc,
        pose: farsight_interfaces::transport::ipc::Publisher<Pose>,
        local: farsight_interfaces::transport::ipc::SlicePublisher<CostmapHeader, CostCell>,
        polar: farsight_interfaces::transport::ipc::SlicePublisher<PolarBinsHeader, PolarCell>,
    }

    impl FusionRig {
        fn start(
            ns: &Namespace,
            bus: &farsight_interfaces::transport::ipc::Bus,
            cfg: &std::path::Path,
        ) -> Self {
            Self {
                fused: bus.slice_subscriber(&topics::costmap("fused")).unwrap(),
                health: bus.subscriber(&topics::health("costmap-fusion")).unwrap(),
                fusion: ns.start_stage("farsight-costmap-fusion", "costmap-fusion", cfg),
                pose: bus.publisher(&topics::pose()).unwrap(),
                local: bus
                    .slice_publisher(&topics::costmap("local"), 21 * 21)
                    .unwrap(),
                polar: bus.slice_publisher(&topics::polar_bins(), 96).unwrap(),
            }
        }
    }

    /// FITAM's far field is optional: stale on capture time, it leaves the
    /// fused map (the "no far field" map) while the near field goes on. The
    /// near field is required: stale, the maps stop, and their last stamp
    /// ages for the stages downstream.
    #[test]
    fn a_stale_far_field_leaves_the_fused_map_and_a_stale_near_field_stops_it() {
        use farsight_interfaces::fixed::FixedVec;
        let ns = Namespace::new("fusionstale");
        let bus = ns.bus("fusion-stale-test");
        let cfg = ns.write(
            "costmap-fusion.toml",
            "width_cells = 121\nheight_cells = 121\npublish_rate_hz = 20.0\ninput_deadline_s = 0.5\n",
        );
        let FusionRig {
            fused,
            health,
            fusion,
            pose,
            local,
            polar,
        } = FusionRig::start(&ns, &bus, &cfg);
        let (header, cells) = near_field(10, |_, _| false);
        // Every heading, every range: class 2 (0.235 s/m), certain.
        let bins_header = PolarBinsHeader {
            heading_bins: 32,
            first_heading_start_rad: -std::f32::consts::PI,
            heading_width_rad: std::f32::consts::TAU / 32.0,
            range_edges_m: FixedVec::from_slice(&[25.0, 50.0, 75.0, 100.0]).unwrap(),
            ..Default::default()
        };
        let bins = vec![
            PolarCell {
                cost_s_per_m: 1.0 / 4.25,
                variance: 0.01,
                class_id: 2,
                probability: 0.99
            };
            96
        ];
        // Feeds pose, and optionally near and far field, until the fused
        // cell 40 m ahead and the stage's health satisfy `want`.
        let mut seq = 0;
        let mut report: Option<StageHealth> = None;
        type Want<'a> = &'a dyn Fn(f32, &StageHealth) -> bool;
        let mut feed_until = |near: bool, far: bool, what: &str, want: Want| {
            let end = Instant::now() + Duration::from_secs(10);
            loop {
                seq += 1;
                pose.publish(&farsight_tests::pose_now()).unwrap();
                if near {
                    local.publish_copy(restamped(header), &cells).unwrap();
                }
                if far {
                    let mut h = bins_header;
                    h.stamp = farsight_tests::stamp_now(seq);
                    polar.publish_copy(h, &bins).unwrap();
                }
                std::thread::sleep(Duration::from_millis(50));
                // (`latest` gives each message once: keep the last report.)
                if let Some(h) = health.latest().unwrap() {
                    report = Some(h);
                }
                if let (Some(f), Some(report)) = (fused.latest().unwrap(), &report) {
                    let h = *f.header();
                    let ahead = f.data()[h.cell_index(40.0, 0.0).unwrap()].cost_s_per_m;
                    if want(ahead, report) {
                        return *f.header();
                    }
                }
                assert!(
                    Instant::now() < end,
                    "{what}: last {report:?}\n{}",
                    fusion.stderr_so_far()
                );
            }
        };
        let far_field = |c: f32, _: &StageHealth| (c - 1.0 / 4.25).abs() < 0.02;
        feed_until(true, true, "the far field 40 m ahead", &far_field);
        // The far-field stage dies: the map goes on without it (unknown,
        // 1 s/m), and health names it.
        feed_until(true, false, "the far field left out", &|c, h| {
            c == 1.0
                && h.state == HealthState::DEGRADED
                && h.reason.as_str().starts_with("bins/polar is")
                && h.reason.as_str().ends_with("(deadline 0.5 s)")
        });
        // It comes back.
        feed_until(true, true, "the far field again", &far_field);
        // The near field dies: no more maps, though poses still arrive.
        let last = feed_until(false, true, "a map", &|_, _| true);
        std::thread::sleep(Duration::from_millis(1000));
        for k in 0..10 {
            pose.publish(&farsight_tests::pose_now()).unwrap();
            let mut h = bins_header;
            h.stamp = farsight_tests::stamp_now(1000 + k);
            polar.publish_copy(h, &bins).unwrap();
            std::thread::sleep(Duration::from_millis(50));
        }
        let newest = *fused.latest().unwrap().expect("a fused map").header();
        assert!(
            newest.stamp.capture_time_ns <= last.stamp.capture_time_ns + 600_000_000,
            "a map was stamped after the near field died: {newest:?} vs {last:?}"
        );
        let h = farsight_tests::wait_health(&health, Duration::from_secs(5), "stale", |h| {
            h.reason.as_str().starts_with("near field is")
        });
        assert_eq!(h.state, HealthState::DEGRADED);
    }

    /// Malformed near-field costmaps and polar bins from a peer are dropped,
    /// counted and named in health; the stage keeps fusing what is valid.
    #[test]
    fn costmap_fusion_drops_malformed_maps_and_bins_and_keeps_running() {
        use farsight_interfaces::fixed::FixedVec;
        let ns = Namespace::new("fusionbad");
        let bus = ns.bus("fusion-bad-test");
        let cfg = ns.write(
            "costmap-fusion.toml",
            "width_cells = 41\nheight_cells = 41\npublish_rate_hz = 20.0\n",
        );
        let FusionRig {
            fused,
            health,
            fusion,
            pose,
            local,
            polar,
        } = FusionRig::start(&ns, &bus, &cfg);
        pose.publish(&farsight_tests::pose_now()).unwrap();
        std::thread::sleep(Duration::from_millis(100));
        // A header that promises more cells than it carries, and one with a
        // NaN origin.
        let (header, cells) = near_field(10, |x, y| x == 5 && y == 0);
        local.publish_copy(header, &cells[..100]).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        let nan = CostmapHeader {
            x_min_m: f64::NAN,
            ..header
        };
        local.publish_copy(nan, &cells).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        // Polar bins whose last range edge would have the rasteriser walk
        // a billion cells.
        let absurd = PolarBinsHeader {
            heading_bins: 32,
            first_heading_start_rad: -std::f32::consts::PI,
            heading_width_rad: std::f32::consts::TAU / 32.0,
            range_edges_m: FixedVec::from_slice(&[25.0, 50.0, 75.0, 1e9]).unwrap(),
            ..Default::default()
        };
        let bins = vec![
            PolarCell {
                cost_s_per_m: 0.2,
                variance: 0.1,
                class_id: 2,
                probability: 0.9
            };
            96
        ];
        polar.publish_copy(absurd, &bins).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        // Then a valid map: fused as usual.
        let end = Instant::now() + Duration::from_secs(10);
        loop {
            pose.publish(&farsight_tests::pose_now()).unwrap();
            local.publish_copy(restamped(header), &cells).unwrap();
            std::thread::sleep(Duration::from_millis(50));
            if let Some(f) = fused.latest().unwrap() {
                let h = *f.header();
                if f.data()[h.cell_index(5.0, 0.0).unwrap()]
                    .cost_s_per_m
                    .is_infinite()
                {
                    break;
                }
            }
            assert!(
                Instant::now() < end,
                "the valid map never arrived\n{}",
                fusion.stderr_so_far()
            );
        }
        std::thread::sleep(Duration::from_millis(1100)); // a health period
        let h = health.latest().unwrap().expect("fusion health");
        assert!(h.dropped >= 3, "dropped {}: {:?}", h.dropped, h.reason);
        let log = fusion.stderr_so_far();
        for why in ["payload holds 100", "not finite", "range edges"] {
            assert!(log.contains(why), "{why:?} not logged:\n{log}");
        }
    }
}
