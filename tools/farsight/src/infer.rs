//! `farsight infer`: runs a model on image files offline through the same code
//! as the inference stage, and writes what it produced as PNG so a person can
//! check a new model before deploying it:
//!
//! - `<name>.classes.png`: class ids, 8-bit;
//! - `<name>.navigability.png`: 255 = navigable, 8-bit;
//! - `<name>.heatmap.png`: affordance in [0, 1] as 16-bit;
//! - `<name>.overlay.png`: the frame with navigability (green/red) or classes over it.

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
    let mut backend = Backend::Onnx(Box::new(model));
    let files = collect(&a.inputs)?;
    std::fs::create_dir_all(&a.out)?;
    let (mut ok, mut failed) = (0usize, 0usize);
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
                farsight_imaging::overlay(&rgb, fw, fh, w, hh, 0.6, |i| {
                    Some([(hm[i] * 255.0) as u8, 0, 0])
                })
            } else {
                rgb
            };
            write_png(&out("overlay"), fw, fh, PixelEncoding::RGB8, &overlay)?;
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
    Ok(())
}
