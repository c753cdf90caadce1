//! The training set of HIP's learned density (section V, "Training"): the
//! sticky random drive of [`crate::sticky`] (sequences that ended in a
//! collision already cut), subsampled at 5 Hz, each pose an example of
//! what the camera saw there and the H = 10 positions the robot drove
//! next, in its own frame (x ahead, y left: the library's frame,
//! [`farsight_subgoal_selection::hip::future_trajectories`]).
//!
//! Each example also holds the 10 positions before it, 0.2 s apart, in
//! the same frame (the paper's "10 past timesteps"; the subgoal stage
//! feeds a model them from its pose history). Before a sequence's first
//! pose the robot stood there, just respawned: the past repeats it, as the
//! stage's history repeats its oldest pose. The paper's depth channel is
//! not here: the stage feeds a model one RGB image.
//!
//! With a trajectory library, each example also says which of its
//! trajectories, driven from the pose, would keep the robot's disc off
//! every lethal cell: the traversable set the learned cost should rank
//! above the rest (section II: q "should assign high values to a subset
//! of the traversable trajectories and low values to this subset's
//! complement"), which is how the trainer judges it.
//!
//! A folder:
//!
//! ```text
//! hip-dataset.toml     what made it (scenario, seeds, sizes) and the counts
//! examples.csv         example,segment,t_s,x_m,y_m,yaw_rad,fx1_m,fy1_m,...,fx10_m,fy10_m,px1_m,py1_m,...,px10_m,py10_m[,library_free]
//! images/NNNNNN.png    the front camera at the pose, resized to the model input as the inference stage resizes it
//! ```
//!
//! The past runs oldest first (`px1` is 2 s before). `library_free` is one
//! character per library trajectory, `1` free and `0` into something
//! lethal.

use crate::render::{Frame, Renderer};
use crate::robot::Robot;
use crate::sticky::StickyDrive;
use crate::world::World;
use anyhow::{Context, Result};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// One example: the pose the camera saw from and the future after it.
#[derive(Debug, Clone, PartialEq)]
pub struct HipExample {
    pub segment: usize,
    pub t_s: f64,
    /// World pose `[x_m, y_m, yaw_rad]`.
    pub pose: [f64; 3],
    /// The next `horizon` positions, robot frame (x ahead, y left), metres.
    pub future: Vec<[f64; 2]>,
    /// The `past` positions before, oldest first, same frame.
    pub past: Vec<[f64; 2]>,
}

/// Every pose of every collision-free sequence that has `horizon` recorded
/// poses after it (the drive records at a fixed rate, so the k-th pose
/// after is `k` record steps later), as the library's futures are made,
/// with the `past` poses before it (the sequence's first repeated before
/// its start).
pub fn hip_examples(drive: &StickyDrive, horizon: usize, past: usize) -> Vec<HipExample> {
    let mut out = Vec::new();
    for (segment, poses) in drive.segments.iter().enumerate() {
        for i in 0..poses.len().saturating_sub(horizon) {
            let (t_s, x0, y0, yaw0) = poses[i];
            let (s, c) = yaw0.sin_cos();
            let frame = |&(_, x, y, _): &(f64, f64, f64, f64)| {
                let (dx, dy) = (x - x0, y - y0);
                [c * dx + s * dy, -s * dx + c * dy]
            };
            out.push(HipExample {
                segment,
                t_s,
                pose: [x0, y0, yaw0],
                future: poses[i + 1..=i + horizon].iter().map(frame).collect(),
                past: (1..=past)
                    .rev()
                    .map(|k| frame(&poses[i.saturating_sub(k)]))
                    .collect(),
            });
        }
    }
    out
}

/// Which of `library`'s trajectories (robot frame), started from world
/// `pose`, keep a disc of `radius_m` off every lethal cell at each point.
pub fn library_free(
    world: &World,
    pose: [f64; 3],
    library: &[Vec<[f64; 2]>],
    radius_m: f64,
) -> Vec<bool> {
    let (s, c) = pose[2].sin_cos();
    library
        .iter()
        .map(|t| {
            t.iter().all(|&[x, y]| {
                let (wx, wy) = (pose[0] + c * x - s * y, pose[1] + s * x + c * y);
                Robot::footprint_free(world, wx, wy, radius_m)
            })
        })
        .collect()
}

/// The library the examples are judged against, and the disc.
#[derive(Debug, Clone)]
pub struct LibraryCheck<'a> {
    pub trajectories: &'a [Vec<[f64; 2]>],
    pub radius_m: f64,
}

/// What made a dataset folder, written as `hip-dataset.toml`.
#[derive(Debug, Clone, Serialize)]
pub struct HipDatasetManifest {
    pub format: u32,
    pub scenario: String,
    /// The scenario's seed and the drive's.
    pub seed: u64,
    pub drive_seconds: f64,
    pub collisions_removed: usize,
    pub sequences: usize,
    pub examples: usize,
    pub horizon: usize,
    /// Past positions per example.
    pub past: usize,
    pub step_s: f64,
    /// The camera rendered (the simulator's front camera) and the model
    /// input it was resized to.
    pub camera_width: u32,
    pub camera_height: u32,
    pub image_width: u32,
    pub image_height: u32,
    /// The library of `library_free` ("" when none) and its disc.
    pub library: String,
    pub library_radius_m: f64,
}

/// Renders every example's view with `camera` and writes the folder at
/// `out` (made if missing; an existing `examples.csv` is replaced).
/// `progress(done, total)` is called every few hundred examples.
pub fn write_hip_dataset(
    out: &Path,
    world: &World,
    camera: &Camera,
    examples: &[HipExample],
    manifest: &HipDatasetManifest,
    library: Option<&LibraryCheck>,
    mut progress: impl FnMut(usize, usize),
) -> Result<()> {
    let images = out.join("images");
    std::fs::create_dir_all(&images).with_context(|| format!("creating {}", images.display()))?;
    let (cw, ch) = (camera.model.width, camera.model.height);
    let (iw, ih) = (manifest.image_width, manifest.image_height);
    let mut renderer = Renderer::new(camera, 150.0);
    let mut frame = Frame::default();
    let mut resizer = farsight_dataset::model_input_resizer(iw, ih);
    let header = ImageHeader::packed(Stamp::default(), camera.id, cw, ch, PixelEncoding::RGB8);
    let mut csv = String::from("example,segment,t_s,x_m,y_m,yaw_rad");
    for k in 1..=manifest.horizon {
        write!(csv, ",fx{k}_m,fy{k}_m")?;
    }
    for k in 1..=manifest.past {
        write!(csv, ",px{k}_m,py{k}_m")?;
    }
    if library.is_some() {
        csv.push_str(",library_free");
    }
    csv.push('\n');
    for (n, e) in examples.iter().enumerate() {
        renderer.render(world, e.pose, &mut frame);
        let small = farsight_dataset::model_input_rgb(&mut resizer, &header, &frame.rgb, iw, ih)
            .map_err(|err| anyhow::anyhow!("example {n}: resizing the view: {err}"))?;
        let path = images.join(format!("{n:06}.png"));
        farsight_dataset::write_png(&path, iw as usize, ih as usize, 3, &small)?;
        let [x, y, yaw] = e.pose;
        write!(csv, "{n},{},{:.3},{x:.4},{y:.4},{yaw:.5}", e.segment, e.t_s)?;
        for p in e.future.iter().chain(&e.past) {
            write!(csv, ",{:.4},{:.4}", p[0], p[1])?;
        }
        if let Some(l) = library {
            csv.push(',');
            for free in library_free(world, e.pose, l.trajectories, l.radius_m) {
                csv.push(if free { '1' } else { '0' });
            }
        }
        csv.push('\n');
        if n % 500 == 0 || n + 1 == examples.len() {
            progress(n + 1, examples.len());
        }
    }
    let csv_path = out.join("examples.csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    let toml_path = out.join("hip-dataset.toml");
    std::fs::write(&toml_path, toml::to_string(manifest)?)
        .with_context(|| format!("writing {}", toml_path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(segments: Vec<Vec<(f64, f64, f64, f64)>>) -> StickyDrive {
        StickyDrive {
            segments,
            collisions: 0,
        }
    }

    #[test]
    fn futures_are_the_next_poses_in_the_robot_frame() {
        // Facing +y (yaw 90 degrees) and driving along it at 1 m per record:
        // the future runs straight ahead, x = 1, 2, 3 m, y = 0.
        let yaw = std::f64::consts::FRAC_PI_2;
        let poses: Vec<_> = (0..5)
            .map(|k| (0.2 * k as f64, 10.0, 5.0 + k as f64, yaw))
            .collect();
        let ex = hip_examples(&drive(vec![poses]), 3, 2);
        assert_eq!(ex.len(), 2, "poses 0 and 1 have three after them");
        // Pose 1's past: pose 0 one metre behind, and before it pose 0
        // again (the robot stood at its spawn).
        assert_eq!(ex[1].past.len(), 2);
        for p in &ex[1].past {
            assert!((p[0] + 1.0).abs() < 1e-12 && p[1].abs() < 1e-12, "{p:?}");
        }
        assert!(
            ex[0].past.iter().all(|p| p[0].abs() < 1e-12),
            "{:?}",
            ex[0].past
        );
        for (i, e) in ex.iter().enumerate() {
            assert_eq!(e.pose, [10.0, 5.0 + i as f64, yaw]);
            for (k, p) in e.future.iter().enumerate() {
                assert!((p[0] - (k + 1) as f64).abs() < 1e-12, "{p:?}");
                assert!(p[1].abs() < 1e-12, "{p:?}");
            }
        }
        // A point to the robot's left is +y: facing +x, a pose at world +y.
        let left = vec![(0.0, 0.0, 0.0, 0.0), (0.2, 0.0, 1.0, 0.0)];
        let ex = hip_examples(&drive(vec![left]), 1, 0);
        assert_eq!(ex[0].future, vec![[0.0, 1.0]]);
    }

    #[test]
    fn examples_stay_inside_their_sequence() {
        // Two sequences, 4 and 2 poses: with H = 2 only the first has
        // examples (poses 0 and 1); none spans the cut between them.
        let a: Vec<_> = (0..4)
            .map(|k| (0.2 * k as f64, k as f64, 0.0, 0.0))
            .collect();
        let b: Vec<_> = (0..2)
            .map(|k| (5.0 + 0.2 * k as f64, 50.0, 0.0, 0.0))
            .collect();
        let ex = hip_examples(&drive(vec![a, b]), 2, 3);
        assert_eq!(ex.len(), 2);
        assert!(ex.iter().all(|e| e.segment == 0));
        assert_eq!(ex[1].future, vec![[1.0, 0.0], [2.0, 0.0]]);
        assert_eq!(
            ex[1].past,
            vec![[-1.0, 0.0], [-1.0, 0.0], [-1.0, 0.0]],
            "pose 0 three times"
        );
        assert!(hip_examples(&drive(vec![]), 10, 10).is_empty());
    }

    #[test]
    fn a_library_trajectory_is_free_unless_the_disc_meets_something_lethal() {
        use crate::world::{Cover, Obstacle};
        let mut world = World::new(30, 30, Cover::Grass);
        world.set_obstacle(15, 10, Obstacle::Stone);
        // Straight ahead 5 m and left 5 m (robot frame), from (10, 10):
        // the stone's cell (15, 10) lies along +x.
        let lib = vec![
            (1..=5).map(|k| [k as f64, 0.0]).collect::<Vec<_>>(),
            (1..=5).map(|k| [0.0, k as f64]).collect(),
        ];
        assert_eq!(
            library_free(&world, [10.0, 10.0, 0.0], &lib, 0.4),
            vec![false, true],
            "facing +x, straight runs into the stone"
        );
        assert_eq!(
            library_free(&world, [10.0, 10.0, std::f64::consts::FRAC_PI_2], &lib, 0.4),
            vec![true, true],
            "facing +y, straight is +y and left is -x: both clear"
        );
        assert_eq!(
            library_free(
                &world,
                [10.0, 10.0, std::f64::consts::FRAC_PI_2],
                &lib[1..],
                0.4
            ),
            vec![true]
        );
        // Facing -y, left is +x: into the stone.
        assert_eq!(
            library_free(
                &world,
                [10.0, 10.0, -std::f64::consts::FRAC_PI_2],
                &lib,
                0.4
            ),
            vec![true, false]
        );
    }

    #[test]
    fn the_folder_holds_an_image_and_a_row_per_example() {
        let world = World::new(40, 40, crate::world::Cover::Grass);
        let poses: Vec<_> = (0..6)
            .map(|k| (0.2 * k as f64, 10.0 + 0.3 * k as f64, 20.0, 0.0))
            .collect();
        let examples = hip_examples(&drive(vec![poses]), 3, 2);
        let dir = std::env::temp_dir().join(format!("hip-dataset-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let manifest = HipDatasetManifest {
            format: 1,
            scenario: "test".into(),
            seed: 2,
            drive_seconds: 1.2,
            collisions_removed: 0,
            sequences: 1,
            examples: examples.len(),
            horizon: 3,
            past: 2,
            step_s: 0.2,
            camera_width: 64,
            camera_height: 36,
            image_width: 32,
            image_height: 18,
            library: "test".into(),
            library_radius_m: 0.4,
        };
        let cam = crate::run::front_camera(64, 36);
        let mut calls = Vec::new();
        let lib = vec![vec![[1.0, 0.0]], vec![[0.0, 1.0]]];
        let check = LibraryCheck {
            trajectories: &lib,
            radius_m: 0.4,
        };
        write_hip_dataset(
            &dir,
            &world,
            &cam,
            &examples,
            &manifest,
            Some(&check),
            |d, t| calls.push((d, t)),
        )
        .unwrap();
        let csv = std::fs::read_to_string(dir.join("examples.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 1 + 3, "a header and three examples");
        assert_eq!(lines[0].split(',').count(), 6 + 2 * 3 + 2 * 2 + 1);
        assert!(
            lines[0].contains("fy3_m,px1_m,py1_m,px2_m,py2_m,library_free"),
            "{}",
            lines[0]
        );
        assert!(lines[1].starts_with("0,0,0.000,10.0000,20.0000,0.00000,0.3000,0.0000"));
        assert!(lines[1].ends_with(",11"), "open grass: {}", lines[1]);
        for n in 0..3 {
            let png = std::fs::read(dir.join(format!("images/{n:06}.png"))).unwrap();
            let (h, data) = farsight_imaging::decode_png(&png).unwrap();
            assert_eq!((h.width, h.height, data.len()), (32, 18, 32 * 18 * 3));
        }
        assert_eq!(calls.last(), Some(&(3, 3)));
        let m = std::fs::read_to_string(dir.join("hip-dataset.toml")).unwrap();
        assert!(m.contains("examples = 3"), "{m}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
