//! `farsight dataset`: self-supervised training sets from recordings (LRN
//! hotspots and FITAM far-field classes; see `farsight-dataset`).

use anyhow::{bail, Context, Result};
use clap::Args;
use farsight_dataset::{build, DatasetOptions};
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct DatasetArgs {
    /// Recordings with camera/<name>/image and /info, state/pose and costmap/local.
    #[arg(required = true)]
    recordings: Vec<PathBuf>,
    /// Output folder (created).
    #[arg(long)]
    out: PathBuf,
    /// The camera to label.
    #[arg(long, default_value = "front")]
    camera: String,
    /// Use every n-th frame.
    #[arg(long, default_value_t = 5)]
    every: usize,
    /// Stored image (model input) size, WxH.
    #[arg(long, default_value = "160x96")]
    image_size: String,
    /// FITAM image slices across the frame.
    #[arg(long, default_value_t = 20)]
    slices: usize,
    /// Example PNGs under summary/.
    #[arg(long, default_value_t = 6)]
    examples: usize,
}

pub fn run(a: DatasetArgs) -> Result<()> {
    let Some((w, h)) = a.image_size.split_once('x') else {
        bail!("--image-size {:?}: want WxH, e.g. 160x96", a.image_size);
    };
    let parse = |s: &str| {
        s.parse::<u32>().with_context(|| {
            format!(
                "--image-size {:?}: {s:?} is not a whole number",
                a.image_size
            )
        })
    };
    let opts = DatasetOptions {
        camera: a.camera,
        every: a.every,
        image_width: parse(w)?,
        image_height: parse(h)?,
        slices: a.slices,
        examples: a.examples,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let summary = build(&a.recordings, &a.out, &opts, |line| eprintln!("{line}"))?;
    print!("{summary}");
    println!(
        "dataset in {} ({:.1} s); examples in {}",
        a.out.display(),
        t.elapsed().as_secs_f64(),
        a.out.join("summary").display()
    );
    Ok(())
}
