//! `farsight-sim`: the simulator's command line.
//!
//! ```text
//! farsight-sim render --scenario bug-trap --out out/sim   # one RGB/class/depth view as PNGs, and the map
//! farsight-sim bench                                      # renderer frames/s at 640x360, one core
//! farsight-sim run --scenario bug-trap                    # join the stage graph as the robot
//! farsight-sim hip-dataset --out data/hip                 # HIP's learned density's training set
//! ```

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use farsight_sim::render::{Frame, Renderer, PALETTE};
use farsight_sim::run::{front_camera, RunArgs};
use farsight_sim::scenario::scenario;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "farsight-sim",
    version,
    about = "farsight's off-road simulator"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// HIP's data collection (`hip-library`, `hip-dataset`).
#[derive(clap::Args)]
struct DriveArgs {
    #[arg(long, default_value = "hip-in-distribution")]
    scenario: String,
    /// Simulated seconds of driving, respawns included.
    #[arg(long, default_value_t = 1800.0)]
    seconds: f64,
    /// The drive's seed, and the scenario's (HIP's worlds are fixed; the
    /// seed draws their spawns).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Points per future trajectory H (the paper: 10, at 5 Hz).
    #[arg(long, default_value_t = 10)]
    horizon: usize,
}

#[derive(Subcommand)]
enum Command {
    /// Render the start view of a scenario (RGB, class ids, depth) and its map as PNGs.
    Render {
        #[arg(long, default_value = "bug-trap")]
        scenario: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value_t = 640)]
        width: u32,
        #[arg(long, default_value_t = 360)]
        height: u32,
        #[arg(long, default_value = "out/sim")]
        out: PathBuf,
    },
    /// Join the stage graph as the robot and drive the scenario.
    Run(RunArgs),
    /// HIP's trajectory library (section III) from its data collection:
    /// sticky random actions on a scenario's world, respawned after every
    /// collision, the sequences that ended in one removed, the futures
    /// clustered by k-means. Written as subgoal-selection's `hip_library`.
    HipLibrary {
        #[command(flatten)]
        drive: DriveArgs,
        /// Library size K (the paper: 200).
        #[arg(long, default_value_t = 200)]
        k: usize,
        #[arg(long, default_value = "hip-library.toml")]
        out: PathBuf,
    },
    /// The training set of HIP's learned density (section V): the same
    /// sticky random drive as `hip-library`, every 5 Hz pose with 10 poses
    /// after it an example of the front camera's view there and the
    /// future, robot frame (`farsight_train.py hip` reads the folder).
    /// About 1.7 examples come of a second driven on hip-in-distribution.
    HipDataset {
        #[command(flatten)]
        drive: DriveArgs,
        /// The model input the views are resized to, as the inference
        /// stage resizes the simulator's 640x360 camera.
        #[arg(long, default_value_t = 128)]
        image_width: u32,
        #[arg(long, default_value_t = 72)]
        image_height: u32,
        /// Past positions per example, one record step (0.2 s) apart
        /// (the paper: 10).
        #[arg(long, default_value_t = 10)]
        past: usize,
        /// A HIP library: each example also says which of its
        /// trajectories would be free of lethal cells from the pose.
        #[arg(long)]
        library: Option<PathBuf>,
        #[arg(long)]
        out: PathBuf,
    },
    /// Renderer frames per second at 640x360, per scenario.
    Bench {
        #[arg(long, default_value_t = 60)]
        frames: usize,
        /// Column bands rendered at once (default: the cores, at most 4).
        #[arg(long)]
        threads: Option<usize>,
    },
}

fn write_png(
    path: &std::path::Path,
    w: u32,
    h: u32,
    enc: PixelEncoding,
    data: &[u8],
) -> Result<()> {
    let header = ImageHeader::packed(Stamp::default(), 0, w, h, enc);
    let png = farsight_imaging::encode_png(&header, data)?;
    std::fs::write(path, png).with_context(|| format!("writing {}", path.display()))
}

/// HIP's data collection for `hip-library` and `hip-dataset`: the
/// scenario, the drive's settings and the drive, the arguments checked.
fn sticky_drive(
    &DriveArgs {
        scenario: ref name,
        seconds,
        seed,
        horizon,
    }: &DriveArgs,
) -> Result<(
    farsight_sim::scenario::Scenario,
    farsight_sim::sticky::StickyConfig,
    farsight_sim::sticky::StickyDrive,
)> {
    use farsight_sim::sticky::{sticky_random_drive, StickyConfig};
    anyhow::ensure!(
        seconds.is_finite() && (1.0..=1e6).contains(&seconds),
        "--seconds {seconds}: expected 1 to 1,000,000 simulated seconds"
    );
    anyhow::ensure!(
        (1..=100).contains(&horizon),
        "--horizon {horizon}: expected 1-100 points"
    );
    let s = scenario(name, seed)?;
    let cfg = StickyConfig {
        duration_s: seconds,
        ..Default::default()
    };
    eprintln!("driving {seconds:.0} s of sticky random actions on {name} ...");
    let drive = sticky_random_drive(&s.world, &cfg, seed);
    Ok((s, cfg, drive))
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Run(a) => {
            farsight_sim::run::run(a)?;
        }
        Command::Render {
            scenario: name,
            seed,
            width,
            height,
            out,
        } => {
            let s = scenario(&name, seed)?;
            std::fs::create_dir_all(&out)?;
            let cam = front_camera(width, height);
            let mut f = Frame::default();
            Renderer::new(&cam, 150.0).render(&s.world, s.start, &mut f);
            write_png(
                &out.join(format!("{name}-rgb.png")),
                width,
                height,
                PixelEncoding::RGB8,
                &f.rgb,
            )?;
            let classes: Vec<u8> = f
                .class_ids
                .iter()
                .flat_map(|&c| PALETTE[c as usize])
                .collect();
            write_png(
                &out.join(format!("{name}-classes.png")),
                width,
                height,
                PixelEncoding::RGB8,
                &classes,
            )?;
            let depth: Vec<u8> = f
                .depth_m
                .iter()
                .flat_map(|&d| ((d.min(100.0) / 100.0 * 65535.0) as u16).to_le_bytes())
                .collect();
            write_png(
                &out.join(format!("{name}-depth.png")),
                width,
                height,
                PixelEncoding::MONO16,
                &depth,
            )?;
            let (mw, mh) = (s.world.width, s.world.height);
            let mut map = vec![0u8; mw * mh * 3];
            for y in 0..mh {
                for x in 0..mw {
                    let look = s.world.look(x as i64, y as i64);
                    let row = mh - 1 - y; // north up
                    map[(row * mw + x) * 3..][..3]
                        .copy_from_slice(&PALETTE[look.top_class as usize]);
                }
            }
            for (p, colour) in [
                ([s.start[0], s.start[1]], [255, 255, 255]),
                (s.goal, [255, 0, 0]),
            ] {
                let (cx, cy) = s.world.cell_of(p[0], p[1]);
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (x, y) = (cx + dx, cy + dy);
                        if s.world.contains(x, y) {
                            let row = mh - 1 - y as usize;
                            map[(row * mw + x as usize) * 3..][..3].copy_from_slice(&colour);
                        }
                    }
                }
            }
            write_png(
                &out.join(format!("{name}-map.png")),
                mw as u32,
                mh as u32,
                PixelEncoding::RGB8,
                &map,
            )?;
            println!(
                "wrote {name}-{{rgb,classes,depth,map}}.png to {}",
                out.display()
            );
        }
        Command::HipLibrary {
            drive: args,
            k,
            out,
        } => {
            use farsight_sim::sticky::trajectory_library;
            anyhow::ensure!(
                (1..=10_000).contains(&k),
                "--k {k}: expected 1-10000 trajectories"
            );
            let (_, cfg, drive) = sticky_drive(&args)?;
            let (name, seconds, seed, horizon) =
                (args.scenario, args.seconds, args.seed, args.horizon);
            let poses: usize = drive.segments.iter().map(|s| s.len()).sum();
            let mut lib = trajectory_library(&drive, k, horizon, cfg.record_every_s, seed);
            // Millimetres are plenty for a planner on 1 m cells.
            for p in lib.trajectories.iter_mut().flatten().flatten() {
                *p = (*p * 1000.0).round() / 1000.0;
            }
            anyhow::ensure!(
                lib.trajectories.len() == k,
                "only {} futures of {horizon} points were recorded, fewer than --k {k}: drive longer",
                lib.trajectories.len()
            );
            let header = format!(
                "# HIP trajectory library: farsight-sim hip-library --scenario {name} --seconds {seconds} --seed {seed} --k {k} --horizon {horizon}\n# {poses} collision-free poses at 5 Hz in {} sequences, {} collisions removed.\n",
                drive.segments.len(),
                drive.collisions
            );
            let text = header + &toml::to_string(&lib)?;
            std::fs::write(&out, text).with_context(|| format!("writing {}", out.display()))?;
            println!(
                "wrote {} ({k} trajectories of {horizon} points from {poses} poses, {} collisions)",
                out.display(),
                drive.collisions
            );
        }
        Command::HipDataset {
            drive: args,
            image_width,
            image_height,
            past,
            library,
            out,
        } => {
            anyhow::ensure!(past <= 100, "--past {past}: expected at most 100 points");
            use farsight_sim::hip_dataset::{
                hip_examples, write_hip_dataset, HipDatasetManifest, LibraryCheck,
            };
            let lib: Option<farsight_subgoal_selection::hip::LibraryFile> = library
                .as_deref()
                .map(farsight_stage::load_config_file)
                .transpose()?;
            anyhow::ensure!(
                (8..=1024).contains(&image_width)
                    && (8..=1024).contains(&image_height)
                    && image_width % 8 == 0
                    && image_height % 8 == 0,
                "--image-width {image_width} / --image-height {image_height}: expected 8-1024 pixels each, multiples of 8 (the trainer's encoder halves them three times)"
            );
            let (s, cfg, drive) = sticky_drive(&args)?;
            let (name, seconds, seed, horizon) =
                (args.scenario, args.seconds, args.seed, args.horizon);
            let examples = hip_examples(&drive, horizon, past);
            anyhow::ensure!(
                !examples.is_empty(),
                "no collision-free sequence had {horizon} poses after a pose: drive longer"
            );
            let camera = front_camera(640, 360);
            let manifest = HipDatasetManifest {
                format: 1,
                scenario: name.clone(),
                seed,
                drive_seconds: seconds,
                collisions_removed: drive.collisions,
                sequences: drive.segments.len(),
                examples: examples.len(),
                horizon,
                past,
                step_s: cfg.record_every_s,
                camera_width: camera.model.width,
                camera_height: camera.model.height,
                image_width,
                image_height,
                library: library
                    .as_deref()
                    .map_or(String::new(), |p| p.display().to_string()),
                library_radius_m: cfg.limits.radius_m,
            };
            let check = lib.as_ref().map(|l| LibraryCheck {
                trajectories: &l.trajectories,
                radius_m: cfg.limits.radius_m,
            });
            let t0 = Instant::now();
            write_hip_dataset(
                &out,
                &s.world,
                &camera,
                &examples,
                &manifest,
                check.as_ref(),
                |done, total| {
                    eprint!(
                        "\rrendering views {done}/{total} ({:.0} s)   ",
                        t0.elapsed().as_secs_f64()
                    );
                    if done == total {
                        eprintln!();
                    }
                },
            )?;
            println!(
                "wrote {} ({} examples from {} sequences, {} collisions removed)",
                out.display(),
                examples.len(),
                drive.segments.len(),
                drive.collisions
            );
        }
        Command::Bench { frames, threads } => {
            let cam = front_camera(640, 360);
            let mut r = Renderer::new(&cam, 150.0);
            if let Some(t) = threads {
                r.threads = t;
            }
            println!(
                "renderer at 640x360, {} column bands, {frames} frames per scenario (one run, this machine):\n",
                r.threads
            );
            println!("| scenario | frames/s | ms/frame |");
            println!("|---|---|---|");
            let mut f = Frame::default();
            for name in [
                "bug-trap",
                "bridge",
                "road-forest",
                "obstacle-field-5",
                "random",
            ] {
                let s = scenario(name, 1)?;
                r.render(&s.world, s.start, &mut f); // warm-up
                let t = Instant::now();
                for k in 0..frames {
                    let pose = [s.start[0], s.start[1], s.start[2] + 0.01 * k as f64];
                    r.render(&s.world, pose, &mut f);
                }
                let per = t.elapsed().as_secs_f64() / frames.max(1) as f64;
                println!("| {name} | {:.0} | {:.2} |", 1.0 / per, per * 1e3);
            }
        }
    }
    Ok(())
}
