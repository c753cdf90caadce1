//! `farsight hip-library`: builds HIP's trajectory library (section III) from
//! recorded poses: every sample's future `horizon` positions, `step_s` apart,
//! in its own robot frame, clustered by k-means into `k` centroids, written
//! as the TOML file subgoal-selection's `hip_library` reads.
//!
//! Input: a CSV of poses `t_s,x_m,y_m,yaw_rad` in time order (local ENU; a
//! header line is skipped). Reading poses straight from an MCAP recording
//! follows with the recorder (issue 7).
//!
//! ```text
//! farsight hip-library poses.csv --k 200 --horizon 10 --step-s 0.2 --out hip-library.toml
//! ```

use anyhow::{bail, Context, Result};
use clap::Args;
use farsight_subgoal_selection::hip::{future_trajectories, kmeans, LibraryFile};
use std::path::PathBuf;

#[derive(Args)]
pub struct HipLibraryArgs {
    /// CSV of poses: t_s,x_m,y_m,yaw_rad.
    poses: PathBuf,
    /// Library size K (the paper: 200).
    #[arg(long, default_value_t = 200)]
    k: usize,
    /// Points per trajectory H (the paper: 10).
    #[arg(long, default_value_t = 10)]
    horizon: usize,
    /// Seconds between points (the paper subsamples at 5 Hz).
    #[arg(long, default_value_t = 0.2)]
    step_s: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[arg(long, default_value = "hip-library.toml")]
    out: PathBuf,
}

/// Parses `t_s,x_m,y_m,yaw_rad` lines; names the line of any bad value.
pub fn parse_poses(text: &str) -> Result<Vec<(f64, f64, f64, f64)>> {
    let mut poses: Vec<(f64, f64, f64, f64)> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let values: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        let v = match values {
            Ok(v) if v.len() == 4 && v.iter().all(|x| x.is_finite()) => v,
            Err(_) if n == 0 => continue, // a header
            _ => bail!(
                "line {}: {line:?} is not four finite numbers t_s,x_m,y_m,yaw_rad",
                n + 1
            ),
        };
        if poses.last().is_some_and(|p| v[0] < p.0) {
            bail!("line {}: time {} goes backwards", n + 1, v[0]);
        }
        poses.push((v[0], v[1], v[2], v[3]));
    }
    Ok(poses)
}

pub fn run(a: HipLibraryArgs) -> Result<()> {
    let text = std::fs::read_to_string(&a.poses)
        .with_context(|| format!("reading {}", a.poses.display()))?;
    let poses = parse_poses(&text)?;
    let futures = future_trajectories(&poses, a.horizon, a.step_s);
    if futures.is_empty() {
        bail!(
            "{} poses over {:.1} s give no {}-point future at {} s steps",
            poses.len(),
            poses.last().map(|p| p.0 - poses[0].0).unwrap_or(0.0),
            a.horizon,
            a.step_s
        );
    }
    eprintln!(
        "{} poses -> {} future trajectories; k-means into {}...",
        poses.len(),
        futures.len(),
        a.k
    );
    let centroids = kmeans(&futures, a.k, 100, a.seed);
    let file = LibraryFile {
        step_s: a.step_s,
        trajectories: centroids.into_iter().map(|t| t.0).collect(),
    };
    let text = toml::to_string(&file)?;
    std::fs::write(&a.out, format!(
        "# HIP trajectory library: {} centroids of {} trajectories from {}\n# (farsight hip-library --k {} --horizon {} --step-s {} --seed {})\n{text}",
        file.trajectories.len(), futures.len(), a.poses.display(), a.k, a.horizon, a.step_s, a.seed
    ))
    .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "wrote {} trajectories to {}",
        file.trajectories.len(),
        a.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_parse_with_a_header_and_bad_lines_are_named() {
        let p = parse_poses("t_s,x_m,y_m,yaw_rad\n0,0,0,0\n0.1, 0.1, 0, 0\n").unwrap();
        assert_eq!(p, vec![(0.0, 0.0, 0.0, 0.0), (0.1, 0.1, 0.0, 0.0)]);
        let e = parse_poses("0,0,0,0\n0.1,x,0,0\n").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("0.1,x,0,0"), "{e}");
        let e = parse_poses("1,0,0,0\n0.5,0,0,0\n").unwrap_err().to_string();
        assert!(e.contains("backwards"), "{e}");
    }
}
