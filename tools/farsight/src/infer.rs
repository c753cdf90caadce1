//! `farsight infer`: runs a model on image files offline through the same code
//! as the inference stage, and writes what it produced as PNG so a person can
//! check a new model before deploying it:
//!
//! - `<name>.classes.png`: class ids, 8-bit;
//! - `<name>.navigability.png`: 255 = navigable, 8-bit;
//! - `<name>.heatmap.png`: affordance in [0, 1] as 16-bit;
//! - `<name>.log_q.csv`: HIP's log q(tau | o) of each library trajectory;
//! - `<name>.overlay.png`: the frame with navigability (green/red), classes,
//!   the affordance heatmap (from 0.1: red, turning yellow toward 1) or
//!   FITAM's far-field classes over it. The
//!   far field is drawn as three bands across the top, one per radial bin
//!   (the farthest on top), each image slice a block coloured by the
//!   ensemble's class (the slowest red, the fastest green), darker where
//!   the members' mean probability of it is lower.
//!
//! - HIP's learned density (a model with `past_input`, scored over the
//!   trajectory library given by `--hip-library`): the frame with the
//!   library drawn top-down in its lower right corner, robot at the
//!   bottom centre facing up, each trajectory coloured by its rank under
//!   log q (dark blue the least likely, yellow the most; the ten most
//!   likely drawn thicker). The past it is given is a straight drive at
//!   `--hip-past-speed-mps`, as a still image has none.
//!
//! With `--sheet FILE` every overlay also goes, scaled down, into one PNG
//! side by side: a contact sheet to put in a report.

use anyhow::{bail, Context, Result};
use clap::Args;
use farsight_inference::class_table::ClassTableFile;
use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{OnnxModel, Timings};
use farsight_inference::Backend;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct InferArgs {
    /// The model config TOML (see deploy/models/).
    #[arg(long)]
    model_config: PathBuf,
    /// Image files (PNG or JPEG) or folders of them.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output folder.
    #[arg(long, default_value = "out/infer")]
    out: PathBuf,
    /// Also write every overlay, scaled to `--sheet-width`, into this one PNG
    /// (`--sheet-columns` per row, in input order).
    #[arg(long)]
    sheet: Option<PathBuf>,
    /// Width of each overlay on the sheet (pixels; the height keeps the
    /// aspect of the first).
    #[arg(long, default_value_t = 320, value_parser = clap::value_parser!(u32).range(16..=4096))]
    sheet_width: u32,
    /// Overlays per row of the sheet.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
    sheet_columns: u32,
    /// HIP: the trajectory library the model was exported with
    /// (`hip-library.toml`), needed to draw its scores.
    #[arg(long)]
    hip_library: Option<PathBuf>,
    /// HIP: the speed of the straight drive given as the robot's past
    /// positions (m/s).
    #[arg(long, default_value_t = 1.0, value_parser = parse_speed_mps)]
    hip_past_speed_mps: f64,
}

fn parse_speed_mps(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.0..=20.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} m/s: expected 0 <= speed <= 20")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// The colour a fraction `f` of the way from `a` to `b`.
fn lerp_rgb(a: [u8; 3], b: [u8; 3], f: f64) -> [u8; 3] {
    std::array::from_fn(|i| (a[i] as f64 + (b[i] as f64 - a[i] as f64) * f).round() as u8)
}

/// HIP's scores as the library drawn top-down over the frame's lower right
/// corner (see the module docs).
fn hip_overlay(
    rgb: &[u8],
    fw: usize,
    fh: usize,
    library: &[Vec<[f64; 2]>],
    log_q: &[f32],
    past: &[f32],
) -> Result<Vec<u8>> {
    if log_q.len() != library.len() {
        bail!(
            "the model scores {} trajectories but --hip-library holds {}: use the library it was exported with",
            log_q.len(),
            library.len()
        );
    }
    let mut out = rgb.to_vec();
    let side = (fh / 2).min(fw / 2);
    if side < 16 {
        // No room for a legible inset: the frame as it is.
        return Ok(out);
    }
    let (x0, y0) = (fw - side, fh - side);
    // Darken the inset so the lines read on any frame.
    for y in y0..fh {
        for px in out[(y * fw + x0) * 3..(y * fw + fw) * 3].iter_mut() {
            *px /= 3;
        }
    }
    // Metres ahead (up) and to the left (left) -> inset pixels.
    let (ahead_m, half_width_m) = (4.0, 2.5);
    let to_px = |p: [f64; 2]| -> (f64, f64) {
        let u = (0.5 - p[1] / (2.0 * half_width_m)) * side as f64;
        let v = (1.0 - (p[0] + 0.5) / (ahead_m + 0.5)) * side as f64;
        (x0 as f64 + u, y0 as f64 + v)
    };
    let mut plot = |x: f64, y: f64, c: [u8; 3], r: i64| {
        for dy in -r..=r {
            for dx in -r..=r {
                let (px, py) = (x.round() as i64 + dx, y.round() as i64 + dy);
                if px >= x0 as i64 && py >= y0 as i64 && (px as usize) < fw && (py as usize) < fh {
                    let at = (py as usize * fw + px as usize) * 3;
                    out[at..at + 3].copy_from_slice(&c);
                }
            }
        }
    };
    let mut order: Vec<usize> = (0..library.len()).collect();
    order.sort_by(|&a, &b| log_q[a].total_cmp(&log_q[b]));
    let n = order.len();
    for (rank, &k) in order.iter().enumerate() {
        // Dark blue -> magenta -> yellow with the rank.
        let t = rank as f64 / (n.max(2) - 1) as f64;
        let (blue, magenta, yellow) = ([40, 40, 150], [200, 40, 120], [255, 225, 0]);
        let c = if t < 0.5 {
            lerp_rgb(blue, magenta, 2.0 * t)
        } else {
            lerp_rgb(magenta, yellow, 2.0 * t - 1.0)
        };
        let r = if rank + 10 >= n { 1 } else { 0 };
        let points: Vec<(f64, f64)> = std::iter::once([0.0, 0.0])
            .chain(library[k].iter().copied())
            .map(to_px)
            .collect();
        for w in points.windows(2) {
            let steps = ((w[1].0 - w[0].0).hypot(w[1].1 - w[0].1) * 2.0)
                .ceil()
                .max(1.0);
            for i in 0..=steps as usize {
                let f = i as f64 / steps;
                plot(
                    w[0].0 + f * (w[1].0 - w[0].0),
                    w[0].1 + f * (w[1].1 - w[0].1),
                    c,
                    r,
                );
            }
        }
    }
    for p in past.chunks_exact(2) {
        let (x, y) = to_px([p[0] as f64, p[1] as f64]);
        plot(x, y, [200, 200, 200], 1);
    }
    let (x, y) = to_px([0.0, 0.0]);
    plot(x, y, [255, 255, 255], 3);
    Ok(out)
}

/// Colour of class `k` of `n` ordered slowest to fastest: red to yellow to
/// green.
fn speed_class_color(k: usize, n: usize) -> [u8; 3] {
    let t = k as f32 / (n.max(2) - 1) as f32;
    if t < 0.5 {
        [220, (40.0 + 360.0 * t) as u8, 40]
    } else {
        [(220.0 - 360.0 * (t - 0.5)) as u8, 220, 40]
    }
}

/// FITAM's far field as bands over the top of the frame (see the module
/// docs): `shape` is `[slices, radial bins, members, classes]`.
fn far_field_overlay(
    rgb: &[u8],
    fw: usize,
    fh: usize,
    shape: [usize; 4],
    logits: &[f32],
) -> Result<Vec<u8>> {
    use farsight_bin_projection::fitam::{ensemble_observation, FitamBinsConfig};
    let [slices, radial, members, classes] = shape;
    let cfg = FitamBinsConfig {
        // Only the class and its probability are drawn: any speeds do.
        class_speeds_mps: vec![1.0; classes],
        ..Default::default()
    };
    let per_slice = radial * members * classes;
    let cells = (0..slices)
        .map(|s| {
            let l = logits
                .get(s * per_slice..(s + 1) * per_slice)
                .context("far-field output shorter than its shape")?;
            Ok(ensemble_observation(l, radial, members, classes, &cfg)?)
        })
        .collect::<Result<Vec<_>>>()?;
    // Rows of the colour grid: the radial bins (3/16 of the frame for
    // FITAM's three), then the untouched frame.
    let rows = (radial * 16 / 3).max(radial + 1);
    Ok(farsight_imaging::overlay(
        rgb,
        fw,
        fh,
        slices,
        rows,
        0.75,
        |i| {
            let (row, slice) = (i / slices, i % slices);
            let cell = cells[slice].get(radial.checked_sub(row + 1)?)?;
            let c = speed_class_color(cell.class_id as usize, classes);
            let k = 0.25 + 0.75 * cell.probability;
            Some(c.map(|v| (v as f32 * k) as u8))
        },
    ))
}

/// The contact sheet (`--sheet`): each overlay scaled into a `width`-wide
/// cell as it is made (as tall as the first overlay's aspect makes it, at
/// most four widths; another aspect is fitted inside, centred, on white),
/// `columns` a row. Only the scaled cells are kept.
struct ContactSheet {
    width: usize,
    columns: usize,
    cell_height: Option<usize>,
    cells: Vec<(usize, usize, Vec<u8>)>,
    resizer: fast_image_resize::Resizer,
}

impl ContactSheet {
    fn new(width: u32, columns: u32) -> Self {
        Self {
            width: width as usize,
            columns: columns as usize,
            cell_height: None,
            cells: Vec::new(),
            resizer: fast_image_resize::Resizer::new(),
        }
    }

    fn add(&mut self, w: usize, h: usize, rgb: &[u8]) -> Result<()> {
        use fast_image_resize as fir;
        let tw = self.width;
        let th = *self.cell_height.get_or_insert_with(|| {
            ((h as f64) * tw as f64 / w.max(1) as f64)
                .round()
                .clamp(1.0, 4.0 * tw as f64) as usize
        });
        let scale = (tw as f64 / w.max(1) as f64).min(th as f64 / h.max(1) as f64);
        let dw = ((w as f64 * scale).round() as usize).clamp(1, tw);
        let dh = ((h as f64 * scale).round() as usize).clamp(1, th);
        let src = fir::images::ImageRef::new(w as u32, h as u32, rgb, fir::PixelType::U8x3)?;
        let mut dst = fir::images::Image::new(dw as u32, dh as u32, fir::PixelType::U8x3);
        let options = fir::ResizeOptions::new()
            .resize_alg(fir::ResizeAlg::Convolution(fir::FilterType::Lanczos3));
        self.resizer.resize(&src, &mut dst, &options)?;
        self.cells.push((dw, dh, dst.into_vec()));
        Ok(())
    }

    /// The sheet's width, height and pixels (RGB8), `None` without cells.
    fn finish(&self) -> Option<(usize, usize, Vec<u8>)> {
        let (tw, th) = (self.width, self.cell_height?);
        let cols = self.columns.min(self.cells.len());
        let rows = self.cells.len().div_ceil(cols);
        let (sw, sh) = (cols * tw, rows * th);
        let mut sheet = vec![255u8; sw * sh * 3];
        for (k, (dw, dh, cell)) in self.cells.iter().enumerate() {
            let x0 = (k % cols) * tw + (tw - dw) / 2;
            let y0 = (k / cols) * th + (th - dh) / 2;
            for (y, row) in cell.chunks_exact(dw * 3).enumerate() {
                let at = ((y0 + y) * sw + x0) * 3;
                sheet[at..at + dw * 3].copy_from_slice(row);
            }
        }
        Some((sw, sh, sheet))
    }
}

fn collect(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut in_dir: Vec<_> = std::fs::read_dir(p)
                .with_context(|| format!("reading {}", p.display()))?
                .flatten()
                .map(|e| e.path())
                .filter(|f| {
                    f.extension().is_some_and(|e| {
                        ["png", "jpg", "jpeg"]
                            .iter()
                            .any(|x| e.eq_ignore_ascii_case(x))
                    })
                })
                .collect();
            in_dir.sort();
            files.extend(in_dir);
        } else if p.exists() {
            files.push(p.clone());
        } else {
            bail!("{} does not exist", p.display());
        }
    }
    if files.is_empty() {
        bail!("no PNG or JPEG images in {inputs:?}");
    }
    Ok(files)
}

fn write_png(path: &Path, w: usize, h: usize, enc: PixelEncoding, data: &[u8]) -> Result<()> {
    let header = ImageHeader::packed(Stamp::default(), 0, w as u32, h as u32, enc);
    std::fs::write(path, farsight_imaging::encode_png(&header, data)?)
        .with_context(|| format!("writing {}", path.display()))
}

pub fn run(a: InferArgs) -> Result<()> {
    let config = ModelConfig::load(&a.model_config)?;
    let table = config
        .class_table_path()
        .map(|p| ClassTableFile::open(&p))
        .transpose()?;
    let model = OnnxModel::load(&config).context("loading the model")?;
    // A model of the robot's past positions (HIP) is given a straight
    // drive, and its scores are drawn over the library it ranks.
    let past = config.past_input.as_ref().map(|spec| {
        let speed = a.hip_past_speed_mps;
        let t_ns = 100_000_000_000;
        let pose_at = |t: u64| Some([t as f64 * 1e-9 * speed, 0.0, 0.0]);
        farsight_subgoal_selection::hip::past_positions(pose_at, t_ns, spec.points, spec.step_s)
            .expect("a straight drive has a pose at every time")
    });
    let library = match (&past, &a.hip_library) {
        (Some(_), Some(p)) => {
            let library =
                farsight_stage::load_config_file::<farsight_subgoal_selection::hip::LibraryFile>(p)
                    .with_context(|| format!("--hip-library {}", p.display()))?
                    .trajectories;
            let scored = config.outputs.iter().find(|o| {
                o.kind == farsight_inference::model_config::OutputKind::TrajectoryLogLikelihood
            });
            if let Some(o) = scored.filter(|o| o.classes != library.len()) {
                bail!(
                    "--hip-library {}: {} trajectories, but the model scores {} ({} output `{}`): use the library it was exported with",
                    p.display(),
                    library.len(),
                    o.classes,
                    a.model_config.display(),
                    o.name
                );
            }
            Some(library)
        }
        (Some(_), None) => bail!(
            "{}: the model takes past positions and scores a trajectory library; give that library with --hip-library",
            a.model_config.display()
        ),
        (None, _) => None,
    };
    let mut backend = Backend::Onnx(Box::new(model));
    let files = collect(&a.inputs)?;
    std::fs::create_dir_all(&a.out)?;
    let (mut ok, mut failed) = (0usize, 0usize);
    let mut sheet = a
        .sheet
        .as_ref()
        .map(|_| ContactSheet::new(a.sheet_width, a.sheet_columns));
    let mut total = Timings::default();
    for (i, file) in files.iter().enumerate() {
        let stem = file
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("image")
            .to_string();
        let result = (|| -> Result<Timings> {
            let bytes = std::fs::read(file)?;
            // PNG or JPEG, refused from its header above 8192x8192.
            let (h, frame) = farsight_imaging::decode_image(&bytes)?;
            let mut t = Timings::default();
            if let (Some(past), Backend::Onnx(model)) = (&past, &mut backend) {
                // Each run takes the past it was given.
                model.set_past(past)?;
            }
            let p = backend.run(&h, &frame, table.as_ref().map(|t| t.table()), &mut t)?;
            let (w, hh) = (p.width, p.height);
            let out = |suffix: &str| a.out.join(format!("{stem}.{suffix}.png"));
            if let Some(c) = &p.classes {
                write_png(&out("classes"), w, hh, PixelEncoding::MONO8, &c.ids)?;
            }
            if let Some(m) = &p.navigability {
                write_png(&out("navigability"), w, hh, PixelEncoding::MONO8, m)?;
            }
            if let Some(hm) = &p.heatmap {
                write_png(
                    &out("heatmap"),
                    w,
                    hh,
                    PixelEncoding::MONO16,
                    &farsight_imaging::unit_to_mono16(hm),
                )?;
            }
            if let Some(log_q) = &p.trajectory_log_q {
                let csv: String = std::iter::once("trajectory,log_q\n".to_string())
                    .chain(log_q.iter().enumerate().map(|(k, q)| format!("{k},{q}\n")))
                    .collect();
                let path = a.out.join(format!("{stem}.log_q.csv"));
                std::fs::write(&path, csv)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            let rgb = match h.encoding {
                PixelEncoding::RGB8 => frame,
                PixelEncoding::RGBA8 => frame
                    .chunks_exact(4)
                    .flat_map(|p| [p[0], p[1], p[2]])
                    .collect(),
                e => bail!("overlay needs an RGB frame, got {e}"),
            };
            let (fw, fh) = (h.width as usize, h.height as usize);
            let overlay = if let Some(m) = &p.navigability {
                farsight_imaging::overlay(&rgb, fw, fh, w, hh, 0.45, |i| {
                    Some(if m[i] == 255 {
                        [0, 220, 0]
                    } else {
                        [230, 0, 0]
                    })
                })
            } else if let Some(c) = &p.classes {
                farsight_imaging::overlay(&rgb, fw, fh, w, hh, 0.5, |i| {
                    Some(farsight_imaging::class_color(c.ids[i]))
                })
            } else if let Some(hm) = &p.heatmap {
                // Below 0.1 the frame shows through untouched; above, red
                // turning yellow toward 1.
                farsight_imaging::overlay(&rgb, fw, fh, w, hh, 0.6, |i| {
                    (hm[i] >= 0.1).then(|| lerp_rgb([200, 0, 0], [255, 240, 0], hm[i] as f64))
                })
            } else if let Some((shape, logits)) = &p.far_field {
                far_field_overlay(&rgb, fw, fh, *shape, logits)?
            } else if let (Some(log_q), Some(library), Some(past)) =
                (&p.trajectory_log_q, &library, &past)
            {
                hip_overlay(&rgb, fw, fh, library, log_q, past)?
            } else {
                rgb
            };
            write_png(&out("overlay"), fw, fh, PixelEncoding::RGB8, &overlay)?;
            if let Some(sheet) = &mut sheet {
                sheet.add(fw, fh, &overlay)?;
            }
            Ok(t)
        })();
        match result {
            Ok(t) => {
                ok += 1;
                total.preprocess_s += t.preprocess_s;
                total.inference_s += t.inference_s;
                total.postprocess_s += t.postprocess_s;
                println!(
                    "[{}/{}] {} -> {}/{stem}.*.png  (pre {:.1} ms, inference {:.1} ms, post {:.1} ms)",
                    i + 1,
                    files.len(),
                    file.display(),
                    a.out.display(),
                    t.preprocess_s * 1e3,
                    t.inference_s * 1e3,
                    t.postprocess_s * 1e3
                );
            }
            Err(e) => {
                failed += 1;
                eprintln!(
                    "[{}/{}] {}: skipped: {e:#}",
                    i + 1,
                    files.len(),
                    file.display()
                );
            }
        }
    }
    let n = ok.max(1) as f64;
    println!(
        "{ok} images done, {failed} skipped; mean pre {:.1} ms, inference {:.1} ms, post {:.1} ms",
        total.preprocess_s / n * 1e3,
        total.inference_s / n * 1e3,
        total.postprocess_s / n * 1e3
    );
    if ok == 0 {
        bail!("no image could be processed");
    }
    if let (Some(path), Some(sheet)) = (&a.sheet, &sheet) {
        if let Some((w, h, pixels)) = sheet.finish() {
            write_png(path, w, h, PixelEncoding::RGB8, &pixels)?;
            println!(
                "sheet of {} overlays: {}",
                sheet.cells.len(),
                path.display()
            );
        }
    }
    Ok(())
}
