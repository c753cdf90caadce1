//! `farsight bench navigation`: what the image-space navigation stages cost per
//! frame, excluding inference: LRN bins (projection + threshold/normalise/EMA),
//! POVNav (horizon, optic goals, visual path, features) and the servo law.
//!
//! The inputs are a procedural road scene (a navigable trapezoid narrowing to
//! the horizon, with noise specks and an obstacle) and a heatmap hot on the
//! road, so the benchmark needs no model and is the same on every machine.

use crate::bench::NavigationArgs;
use anyhow::Result;
use farsight_bin_projection::{BinGeometry, CameraBins, LrnBins, LrnBinsConfig};
use farsight_interfaces::camera::{Camera, CameraModel, Mount};
use farsight_subgoal_selection::povnav::{plan, safe_half_widths, PovnavConfig};
use farsight_velocity_servoing::{povnav_command, RateLimiter, ServoConfig};
use std::time::Instant;

fn road_scene(w: usize, h: usize) -> (Vec<u8>, Vec<f32>) {
    let mut nav = vec![0u8; w * h];
    let mut heat = vec![0f32; w * h];
    let mut seed = 12345u32;
    for v in h * 2 / 5..h {
        let t = (v - h * 2 / 5) as f64 / (h * 3 / 5) as f64; // 0 at the horizon, 1 at the bottom
        let half = (0.05 + 0.45 * t) * w as f64;
        let centre = w as f64 * (0.5 - 0.1 * (1.0 - t));
        for u in 0..w {
            let on_road = (u as f64 - centre).abs() < half;
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let speck = seed >> 24 < 3;
            let rock = u > w / 2 && u < w / 2 + w / 20 && v > h * 3 / 5 && v < h * 2 / 3;
            if on_road != speck && !rock {
                nav[v * w + u] = 255;
                heat[v * w + u] = (1.0 - t) as f32;
            }
        }
    }
    (nav, heat)
}

fn median_us(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2] * 1e6
}

pub fn run(a: NavigationArgs) -> Result<()> {
    println!("image-space navigation per frame, median of {} runs (one run, this machine's CPU, one core):\n", a.runs);
    println!("| size | LRN bins us | POVNav us | servo us | total us | share of 1 ms |");
    println!("|---|---|---|---|---|---|");
    for (w, h) in [(640usize, 360usize), (1280, 720)] {
        let (nav, heat) = road_scene(w, h);
        let f = w as f64 * 0.8;
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(w as u32, h as u32, f, f, w as f64 / 2.0, h as f64 / 2.0),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.2], [0.0, 0.0, 0.0]),
        );
        let geometry = BinGeometry::from_width_deg(5.0);
        let map = CameraBins::new(&cam, w, h, &geometry); // once per camera, not per frame
        let mut bins = LrnBins::new(geometry, LrnBinsConfig::default());
        let hw = safe_half_widths(h, f, f, h as f64 / 2.0, 1.2, 0.8, 0.2);
        let (pcfg, scfg) = (PovnavConfig::default(), ServoConfig::default());
        let mut limiter = RateLimiter::default();
        let (mut tb, mut tp, mut ts) = (vec![], vec![], vec![]);
        for i in 0..a.runs + 5 {
            let t0 = Instant::now();
            let proj = map.project(&heat, LrnBinsConfig::default().pixel_threshold());
            let out = bins.update(&[proj]);
            let t1 = Instant::now();
            let p = plan(&nav, w, h, 0.3, &hw, &pcfg);
            let t2 = Instant::now();
            let cmd = povnav_command(p.proximity_px, p.alignment_rad, &scfg);
            let cmd = limiter.limit(cmd, 0.05, &scfg);
            let t3 = Instant::now();
            std::hint::black_box((&out, &p, cmd));
            if i >= 5 {
                tb.push((t1 - t0).as_secs_f64());
                tp.push((t2 - t1).as_secs_f64());
                ts.push((t3 - t2).as_secs_f64());
            }
        }
        let (b, p, s) = (median_us(tb), median_us(tp), median_us(ts));
        let total = b + p + s;
        println!(
            "| {w}x{h} | {b:.0} | {p:.0} | {s:.2} | {total:.0} | {:.0}% |",
            total / 10.0
        );
    }
    Ok(())
}
