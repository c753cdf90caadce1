//! `farsight record`, `farsight replay` and `farsight diff`: recorded frame
//! replays (see the `farsight-recording` crate).
//!
//! ```text
//! farsight record --topics 'camera/**' --topics state/pose --out run.mcap   # until Ctrl-C
//! farsight record --info run.mcap                                           # topics, counts, rates
//! farsight replay run.mcap --speed 4                                        # 4x the recorded pace
//! farsight replay run.mcap --lockstep --driving camera/front/image --answer cmd/velocity
//! farsight diff golden.mcap run.mcap --topics 'nav/**' --topics cmd/velocity
//! ```
//!
//! Every input is verified (`farsight_recording::mcap_file`). A file that is
//! not an MCAP file or is damaged (a bad chunk CRC) exits 1 naming the file
//! and the byte offset, before anything is replayed. A truncated file (a
//! recorder killed mid-write) is read up to its last complete chunk: `--info`
//! prints what is there, `replay` plays it, and both then exit 1 naming the
//! offset where the data ends (`replay --allow-truncated` exits 0); `diff`
//! refuses it.

use anyhow::{bail, Context, Result};
use farsight_interfaces::transport::ipc::Bus;
use farsight_interfaces::transport::net::NetBus;
use farsight_recording::diff::{compare, Tolerance};
use farsight_recording::read::Recording;
use farsight_recording::record::{record, record_zenoh, RecordOptions};
use farsight_recording::replay::{replay, Pace, ReplayOptions};
use farsight_recording::write::RecordingWriter;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Topic glob patterns (`*` within a segment, `**` across); default all.
    #[arg(long, value_delimiter = ',')]
    pub topics: Vec<String>,
    #[arg(long, default_value = "farsight.mcap")]
    pub out: PathBuf,
    /// Stop after this many seconds (default: at Ctrl-C / SIGTERM).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Leave out the Foxglove channels (those of the live server: JPEG
    /// images, /tf, calibration, grids, paths, commands, health), which are
    /// written by default so the file opens in the Foxglove app.
    #[arg(long)]
    pub no_foxglove: bool,
    /// Store messages as they are instead of zstd-compressed (less CPU,
    /// much more disk).
    #[arg(long)]
    pub no_compression: bool,
    /// Record from a robot over zenoh (what its bridge exports) instead of
    /// this machine's shared memory: the robot's zenoh endpoint(s), e.g.
    /// tcp/192.168.1.10:7447.
    #[arg(long, value_delimiter = ',')]
    pub connect: Vec<String>,
    /// With --connect: the robot's name (the <robot> of its zenoh keys).
    #[arg(long, default_value = "robot")]
    pub robot: String,
    #[command(flatten)]
    pub login: crate::Login,
    /// Lock-step: after writing each message of this topic (the graph's
    /// answer to a frame, e.g. cmd/velocity) and what came before it,
    /// report its frame number on health/<--instance>; `farsight-sim run
    /// --await-health <instance>` waits for that before its next frame.
    #[arg(long, value_name = "TOPIC")]
    pub ack: Option<String>,
    /// Report on health/<INSTANCE> (with --ack: `recorder` unless given).
    #[arg(long)]
    pub instance: Option<String>,
    /// Print the summary of a recording instead of recording.
    #[arg(long, value_name = "FILE")]
    pub info: Option<PathBuf>,
}

pub fn run_record(a: RecordArgs) -> Result<()> {
    if let Some(file) = a.info {
        let info = Recording::open(&file)?.info()?;
        print!("{info}");
        if let Some(t) = info.truncated {
            bail!("{t}");
        }
        return Ok(());
    }
    if a.ack.is_some() && !a.connect.is_empty() {
        bail!("--ack answers a lock-step simulator on this machine's shared memory; it does not go with --connect");
    }
    let writer = RecordingWriter::create_with(&a.out, !a.no_foxglove, !a.no_compression)?;
    let opts = RecordOptions {
        patterns: if a.topics.is_empty() {
            vec!["**".into()]
        } else {
            a.topics
        },
        duration: a.duration_s.map(Duration::from_secs_f64),
        instance: a
            .instance
            .or_else(|| a.ack.is_some().then(|| "recorder".to_string())),
        ack: a.ack,
        ..Default::default()
    };
    eprintln!("recording {:?} into {}", opts.patterns, a.out.display());
    // The line a parent process (the demo, tests) waits for.
    let ready = || println!("farsight-record ready");
    let report = if a.connect.is_empty() {
        record(&Bus::open("farsight-record")?, writer, &opts, ready)?
    } else {
        let config = a.login.client_config("client", &a.connect)?;
        record_zenoh(&NetBus::open(config, &a.robot)?, writer, &opts, ready)?
    };
    let mut text = String::new();
    for (topic, r) in &report {
        text += &format!(
            "{topic:<34} {:>8} messages {:>10.3} MB  skipped {}\n",
            r.written.messages,
            r.written.bytes as f64 / 1e6,
            // health/*: its frame number is the stage's last output, so a
            // gap there is no lost message.
            r.skipped
                .map_or_else(|| "(not counted)".to_string(), |n| n.to_string())
        );
    }
    text += &format!("wrote {}\n", a.out.display());
    // The file is finished whatever happens here: a parent that has gone
    // (a demo stopped with its recorder) closes our stdout, and the report
    // then goes to stderr instead of ending the recorder with a panic.
    if let Err(e) = std::io::stdout().lock().write_all(text.as_bytes()) {
        eprintln!("stdout: {e}; the report:\n{text}");
    }
    Ok(())
}

#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    pub file: PathBuf,
    /// Topic glob patterns to replay (recorded names); default all.
    #[arg(long, value_delimiter = ',')]
    pub topics: Vec<String>,
    /// Publish a recorded topic under another name: `FROM=TO` (same kind).
    #[arg(long)]
    pub remap: Vec<String>,
    /// A factor of the recorded pace (2 = twice as fast).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Back to back, without pacing.
    #[arg(long)]
    pub as_fast: bool,
    /// Each frame of --driving waits for --answer to carry its sequence number.
    #[arg(long)]
    pub lockstep: bool,
    /// The topic whose frames the graph answers (after remapping).
    #[arg(long)]
    pub driving: Option<String>,
    /// The graph's answer topics (e.g. cmd/velocity); lock-step waits for all.
    #[arg(long, value_delimiter = ',')]
    pub answer: Vec<String>,
    /// Write the answers taken into this recording (every output of every
    /// frame in lock-step; what the golden tests compare).
    #[arg(long)]
    pub record_answers: Option<PathBuf>,
    /// Lock-step: how long to wait for an answer before going on.
    #[arg(long, default_value_t = 2.0)]
    pub timeout_s: f64,
    /// A truncated recording (a recorder killed mid-write) replays up to
    /// its last complete chunk and exits 1 naming where it was cut; with
    /// this it exits 0 (the cut is still reported).
    #[arg(long)]
    pub allow_truncated: bool,
}

pub fn run_replay(a: ReplayArgs) -> Result<()> {
    let remap = a
        .remap
        .iter()
        .map(|r| {
            r.split_once('=')
                .map(|(f, t)| (f.to_string(), t.to_string()))
                .with_context(|| format!("--remap {r:?}: expected FROM=TO"))
        })
        .collect::<Result<Vec<_>>>()?;
    if !(a.speed > 0.0 && a.speed.is_finite()) {
        bail!("--speed {}: expected a positive factor", a.speed);
    }
    if a.lockstep && (a.driving.is_none() || a.answer.is_empty()) {
        bail!("--lockstep needs --driving TOPIC and --answer TOPIC");
    }
    let pace = if a.lockstep {
        Pace::Lockstep {
            timeout: Duration::from_secs_f64(a.timeout_s),
        }
    } else if a.as_fast {
        Pace::AsFast
    } else {
        Pace::Recorded { factor: a.speed }
    };
    let rec = Recording::open(&a.file)?;
    let bus = Bus::open("farsight-replay")?;
    let opts = ReplayOptions {
        topics: if a.topics.is_empty() {
            vec!["**".into()]
        } else {
            a.topics
        },
        remap,
        pace,
        driving_topic: a.driving,
        answer_topics: a.answer,
        ..Default::default()
    };
    let mut out = a
        .record_answers
        .as_deref()
        .map(|p| RecordingWriter::create(p, false))
        .transpose()?;
    let report = replay(&bus, &rec, &opts, out.as_mut())?;
    if let Some(w) = out {
        w.finish()?;
    }
    print!("{report}");
    if !report.unanswered.is_empty() {
        bail!(
            "{} frames were not consumed by the graph",
            report.unanswered.len()
        );
    }
    match report.truncated {
        Some(t) if !a.allow_truncated => {
            bail!("{t}; replayed those (--allow-truncated to accept a cut recording)")
        }
        _ => Ok(()),
    }
}

#[derive(Debug, clap::Args)]
pub struct DiffArgs {
    pub golden: PathBuf,
    pub run: PathBuf,
    /// Topic glob patterns to compare; default all.
    #[arg(long, value_delimiter = ',')]
    pub topics: Vec<String>,
    /// Absolute float tolerance.
    #[arg(long, default_value_t = 1e-4)]
    pub abs: f64,
    /// Relative float tolerance.
    #[arg(long, default_value_t = 1e-4)]
    pub rel: f64,
}

pub fn run_diff(a: DiffArgs) -> Result<()> {
    let (g, r) = (Recording::open(&a.golden)?, Recording::open(&a.run)?);
    let patterns = if a.topics.is_empty() {
        vec!["**".into()]
    } else {
        a.topics
    };
    let diffs = compare(
        &g,
        &r,
        &patterns,
        Tolerance {
            abs: a.abs,
            rel: a.rel,
        },
    )?;
    for d in diffs.iter().take(50) {
        println!("{d}");
    }
    if diffs.is_empty() {
        println!("no differences");
        Ok(())
    } else {
        bail!("{} differences", diffs.len())
    }
}
