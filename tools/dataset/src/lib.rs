//! # farsight-dataset
//!
//! Self-supervised training sets from the robot's own recordings, for the
//! two learned far-field models:
//!
//! - [`lrn`]: LRN's affordance hotspots (LRN section III-A): where the path
//!   the robot drove leaves each frame's view;
//! - [`fitam`]: FITAM's far-field cost classes per image slice and radial
//!   bin (FITAM section IV-B), from the local costmaps of the whole run.
//!
//! A recording needs `camera/<name>/image` and `/info`, `state/pose` and, for
//! FITAM, `costmap/local`; `farsight demo` and `farsight record` write them.
//! `farsight dataset` turns recordings into a folder:
//!
//! ```text
//! dataset.toml        what made it (recordings, options) and the counts
//! frames.csv          frame,recording,index,capture_time_ns,x_m,y_m,z_m,yaw_rad,lrn,hotspot_u_px,hotspot_v_px,hotspot_range_m
//! images/NNNNNN.png   the frame resized to the model input, as the inference stage resizes it (RGB)
//! lrn/NNNNNN.png      grey + alpha: grey = affordance x 255, alpha 255 = labelled, 0 = unlabelled
//! fitam.csv           frame,slice,radial_bin,class,weight (labelled swaths only)
//! summary/*.png       examples: labels over their images
//! ```
//!
//! ```no_run
//! use farsight_dataset::{build, DatasetOptions};
//! let summary = build(&["run.mcap".into()], "data/train".as_ref(), &DatasetOptions::default(), |line| eprintln!("{line}"))?;
//! println!("{summary}");
//! # Ok::<(), farsight_dataset::DatasetError>(())
//! ```

pub mod fitam;
pub mod lrn;
pub mod metrics;
pub mod run;
pub mod summary;

use farsight_bin_projection::fitam::slice_heading_bins;
use farsight_costmap_fusion::labels::LabelRules;
use farsight_costmap_fusion::swath::PolarGeometry;
use farsight_inference::model_config::InputSpec;
use farsight_inference::preprocess::Preprocessor;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::ImageHeader;
use lrn::{lrn_label, visible_path, LrnLabel, LrnLabelConfig};
use run::{for_each_frame, RunIndex};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error(transparent)]
    Recording(#[from] farsight_recording::RecordingError),
    #[error("{path}: {topic}: {why}")]
    Message {
        path: String,
        topic: String,
        why: String,
    },
    #[error("{path}: no {what}")]
    Missing { path: String, what: String },
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{0}")]
    Options(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// FITAM's label geometry and rule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitamLabelConfig {
    pub heading_bins: usize,
    pub range_edges_m: Vec<f64>,
    pub class_speeds_mps: Vec<f64>,
    pub rho_class: f64,
    pub rho_bin: f64,
}

impl Default for FitamLabelConfig {
    fn default() -> Self {
        let g = PolarGeometry::fitam_default();
        let r = LabelRules::default();
        Self {
            heading_bins: g.heading_bins,
            range_edges_m: g.range_edges_m,
            class_speeds_mps: r.class_speeds_mps,
            rho_class: r.rho_class,
            rho_bin: r.rho_bin,
        }
    }
}

impl FitamLabelConfig {
    pub fn geometry(&self) -> PolarGeometry {
        PolarGeometry {
            heading_bins: self.heading_bins,
            first_heading_start_rad: -std::f64::consts::PI,
            heading_width_rad: std::f64::consts::TAU / self.heading_bins as f64,
            range_edges_m: self.range_edges_m.clone(),
        }
    }

    pub fn rules(&self) -> LabelRules {
        LabelRules {
            class_speeds_mps: self.class_speeds_mps.clone(),
            rho_class: self.rho_class,
            rho_bin: self.rho_bin,
            ..Default::default()
        }
    }
}

/// How a dataset is cut from recordings (all written to `dataset.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetOptions {
    /// The camera whose frames are labelled.
    pub camera: String,
    /// Every n-th frame is used (consecutive frames are near duplicates).
    pub every: usize,
    /// Stored image size: the model input size.
    pub image_width: u32,
    pub image_height: u32,
    /// FITAM image slices across the frame (the model's first output axis).
    pub slices: usize,
    /// How far ahead in time the driven path is followed, seconds.
    pub horizon_s: f64,
    /// Example PNGs written under `summary/`.
    pub examples: usize,
    pub lrn: LrnLabelConfig,
    pub fitam: FitamLabelConfig,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        Self {
            camera: "front".into(),
            every: 5,
            image_width: 160,
            image_height: 96,
            slices: 20,
            horizon_s: 120.0,
            examples: 6,
            lrn: LrnLabelConfig::default(),
            fitam: FitamLabelConfig::default(),
        }
    }
}

/// Counts of what a dataset holds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub recordings: usize,
    pub frames: usize,
    /// Frames skipped because no pose was recorded within 100 ms of them.
    pub frames_without_pose: usize,
    pub lrn_frames: usize,
    pub lrn_labelled_px: u64,
    pub lrn_hotspot_px: u64,
    pub lrn_mean_hotspot_range_m: f64,
    /// `[radial bin][class]` labelled swaths.
    pub fitam_counts: Vec<Vec<u64>>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} frames from {} recordings ({} without a pose)",
            self.frames, self.recordings, self.frames_without_pose
        )?;
        writeln!(
            f,
            "LRN: {} frames labelled, {} labelled pixels, {} in hotspots (>= 0.5), mean hotspot range {:.1} m",
            self.lrn_frames, self.lrn_labelled_px, self.lrn_hotspot_px, self.lrn_mean_hotspot_range_m
        )?;
        writeln!(f, "FITAM labelled swaths per radial bin and class:")?;
        for (r, c) in self.fitam_counts.iter().enumerate() {
            writeln!(f, "  radial bin {r}: {c:?}")?;
        }
        Ok(())
    }
}

/// The `dataset.toml` file.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Manifest {
    pub format: u32,
    pub recordings: Vec<String>,
    pub options: DatasetOptions,
    pub summary: Summary,
}

/// The inference stage's preprocessing for a `width` x `height` RGB input
/// with no normalisation, so its output is the resized frame in 0..255.
pub fn model_input_resizer(width: u32, height: u32) -> Preprocessor {
    let spec = InputSpec {
        name: "images".into(),
        layout: Default::default(),
        width,
        height,
        resize: Default::default(),
        color: Default::default(),
        scale: 1.0,
        mean: [0.0; 3],
        std: [1.0; 3],
    };
    Preprocessor::new(&spec)
}

/// The frame resized exactly as the inference stage resizes it for a model
/// input of `width` x `height`, as packed RGB8 (`p` from
/// [`model_input_resizer`], reused across frames).
pub fn model_input_rgb(
    p: &mut Preprocessor,
    header: &ImageHeader,
    rgb: &[u8],
    width: u32,
    height: u32,
) -> Result<Vec<u8>, String> {
    let mut planes = vec![0f32; p.len()];
    p.run(header, rgb, &mut planes).map_err(|e| e.to_string())?;
    let plane = (width * height) as usize;
    Ok((0..plane)
        .flat_map(|i| (0..3).map(move |c| (c, i)))
        .map(|(c, i)| planes[c * plane + i].round().clamp(0.0, 255.0) as u8)
        .collect())
}

/// Writes an 8-bit PNG of `channels` (1 grey, 2 grey+alpha, 3 RGB).
pub fn write_png(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[u8],
) -> Result<(), DatasetError> {
    let file = std::fs::File::create(path).map_err(io(path))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(match channels {
        1 => png::ColorType::Grayscale,
        2 => png::ColorType::GrayscaleAlpha,
        _ => png::ColorType::Rgb,
    });
    enc.set_depth(png::BitDepth::Eight);
    let png_err = |e: png::EncodingError| DatasetError::Io {
        path: path.display().to_string(),
        source: std::io::Error::other(e),
    };
    enc.write_header()
        .map_err(png_err)?
        .write_image_data(data)
        .map_err(png_err)
}

fn lrn_png(label: &LrnLabel) -> Vec<u8> {
    label
        .value
        .iter()
        .zip(&label.labelled)
        .flat_map(|(&v, &l)| [v, if l { 255 } else { 0 }])
        .collect()
}

/// Builds a dataset in `out` from `recordings`; `progress` gets a line now
/// and then.
pub fn build(
    recordings: &[PathBuf],
    out: &Path,
    opts: &DatasetOptions,
    mut progress: impl FnMut(&str),
) -> Result<Summary, DatasetError> {
    if recordings.is_empty() {
        return Err(DatasetError::Options("no recordings given".into()));
    }
    if opts.every == 0 || opts.slices == 0 || opts.image_width == 0 || opts.image_height == 0 {
        return Err(DatasetError::Options(format!(
            "every = {}, slices = {}, image {}x{}: each must be at least 1",
            opts.every, opts.slices, opts.image_width, opts.image_height
        )));
    }
    for d in ["images", "lrn", "summary"] {
        std::fs::create_dir_all(out.join(d)).map_err(io(out))?;
    }
    let geometry = opts.fitam.geometry();
    let rules = opts.fitam.rules();
    let radial = geometry.radial_bins();
    let mut summary = Summary {
        recordings: recordings.len(),
        fitam_counts: vec![vec![0; rules.class_speeds_mps.len()]; radial],
        ..Default::default()
    };
    let frames_path = out.join("frames.csv");
    let mut frames_csv = String::from(
        "frame,recording,index,capture_time_ns,x_m,y_m,z_m,yaw_rad,lrn,hotspot_u_px,hotspot_v_px,hotspot_range_m\n",
    );
    let mut fitam_csv = String::from("frame,slice,radial_bin,class,weight\n");
    let mut range_sum = 0.0;
    let mut frame_id = 0usize;
    let mut examples_left = opts.examples;
    for (ri, path) in recordings.iter().enumerate() {
        let index = RunIndex::read(path, &opts.camera)?;
        if let Some(cut) = &index.truncated {
            progress(&format!("warning: {cut}; using what comes before it"));
        }
        progress(&format!(
            "{}: {} frames, {} poses, {} map cells observed",
            path.display(),
            index.frames,
            index.poses.len(),
            index.seen.len()
        ));
        let cam = &index.camera;
        let label_cam = Camera {
            model: cam.model.scaled_to(opts.image_width, opts.image_height),
            ..cam.clone()
        };
        let slice_bins = slice_heading_bins(cam, opts.slices, geometry.heading_bins);
        let example_every = (index.frames / opts.every / opts.examples.max(1)).max(1);
        let mut done = 0usize;
        let mut resizer = model_input_resizer(opts.image_width, opts.image_height);
        for_each_frame(path, &opts.camera, opts.every, |n, t_ns, header, rgb| {
            done += 1;
            if done.is_multiple_of(50) {
                progress(&format!(
                    "  {} / {} frames",
                    done,
                    index.frames.div_ceil(opts.every)
                ));
            }
            let Some(pi) = index.pose_at(t_ns, 100_000_000) else {
                summary.frames_without_pose += 1;
                return Ok(());
            };
            let pose = index.poses[pi];
            let end = t_ns + (opts.horizon_s * 1e9) as u64;
            let future: Vec<_> = index.poses[pi + 1..]
                .iter()
                .take_while(|p| p.capture_time_ns <= end)
                .copied()
                .collect();
            let id = frame_id;
            frame_id += 1;
            summary.frames += 1;
            let image = model_input_rgb(
                &mut resizer,
                header,
                rgb,
                opts.image_width,
                opts.image_height,
            )
            .map_err(|why| DatasetError::Message {
                path: path.display().to_string(),
                topic: format!("camera/{}/image", opts.camera),
                why,
            })?;
            let (w, h) = (opts.image_width as usize, opts.image_height as usize);
            let img_path = out.join(format!("images/{id:06}.png"));
            write_png(&img_path, w, h, 3, &image)?;
            let visible = visible_path(&label_cam, &pose, &future, &index.seen, &opts.lrn);
            let label = lrn_label(&label_cam, &visible, &opts.lrn);
            if let Some(l) = &label {
                write_png(&out.join(format!("lrn/{id:06}.png")), w, h, 2, &lrn_png(l))?;
                summary.lrn_frames += 1;
                summary.lrn_labelled_px += l.labelled.iter().filter(|&&x| x).count() as u64;
                summary.lrn_hotspot_px += l.value.iter().filter(|&&v| v >= 128).count() as u64;
                range_sum += l.hotspot_range_m;
            }
            let fl = fitam::slice_labels(&geometry, &slice_bins, &pose, &index.seen, &rules);
            for (k, l) in fl.iter().enumerate() {
                if let Some(l) = l {
                    let (s, r) = (k / radial, k % radial);
                    summary.fitam_counts[r][l.class_id] += 1;
                    let _ = writeln!(
                        fitam_csv,
                        "{id},{s},{r},{},{:.4}",
                        l.class_id, l.observed_fraction
                    );
                }
            }
            let p = pose.position_m;
            let _ = writeln!(
                frames_csv,
                "{id},{ri},{n},{t_ns},{:.3},{:.3},{:.3},{:.5},{},{}",
                p[0],
                p[1],
                p[2],
                pose.yaw_rad,
                u8::from(label.is_some()),
                label.as_ref().map_or(",,".to_string(), |l| format!(
                    "{:.2},{:.2},{:.2}",
                    l.hotspot_px[0], l.hotspot_px[1], l.hotspot_range_m
                ))
            );
            if examples_left > 0 && done.is_multiple_of(example_every) && label.is_some() {
                examples_left -= 1;
                let png = summary::example(&image, w, h, label.as_ref(), &fl, opts.slices, radial);
                write_png(
                    &out.join(format!("summary/example_{id:06}.png")),
                    png.0,
                    png.1,
                    3,
                    &png.2,
                )?;
            }
            Ok(())
        })?;
    }
    summary.lrn_mean_hotspot_range_m = range_sum / summary.lrn_frames.max(1) as f64;
    std::fs::write(&frames_path, frames_csv).map_err(io(&frames_path))?;
    let fitam_path = out.join("fitam.csv");
    std::fs::write(&fitam_path, fitam_csv).map_err(io(&fitam_path))?;
    let manifest = Manifest {
        format: 1,
        recordings: recordings.iter().map(|p| p.display().to_string()).collect(),
        options: opts.clone(),
        summary: summary.clone(),
    };
    let text =
        toml::to_string_pretty(&manifest).map_err(|e| DatasetError::Options(e.to_string()))?;
    let manifest_path = out.join("dataset.toml");
    let mut f = std::fs::File::create(&manifest_path).map_err(io(&manifest_path))?;
    f.write_all(
        b"# A farsight training set (format 1); see farsight-dataset's docs for the layout.\n",
    )
    .and_then(|_| f.write_all(text.as_bytes()))
    .map_err(io(&manifest_path))?;
    Ok(summary)
}
