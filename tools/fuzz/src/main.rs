//! `farsight-fuzz`: runs the fuzz targets from their seed corpora.
//!
//! ```text
//! farsight-fuzz                           # every target, 180 s in all
//! farsight-fuzz --seconds 3600            # the long run
//! farsight-fuzz --target wire_ --seconds 60   # the targets whose names start with wire_
//! farsight-fuzz --target mcap --replay target/fuzz-crashes/mcap/0123abcd   # one input, with the panic
//! farsight-fuzz --write-seeds             # regenerate tests/fixtures/fuzz/
//! ```

use clap::Parser;
use farsight_fuzz::{default_crash_dir, fuzz, shares, table, targets, workspace_root, Target};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[global_allocator]
static ALLOC: farsight_fuzz::MeasuringAlloc = farsight_fuzz::MeasuringAlloc;

#[derive(Parser)]
#[command(
    name = "farsight-fuzz",
    about = "Fuzz every input farsight parses; non-zero exit on any panic"
)]
struct Args {
    /// Total time, shared by the targets run (by their weights: MCAP 6,
    /// images 3, ROS CDR and wire images 2, the others 1).
    #[arg(long, default_value_t = 180.0)]
    seconds: f64,
    /// Run only the targets whose names start with this (repeatable).
    #[arg(long)]
    target: Vec<String>,
    /// Seed of the mutations (the same seed makes the same inputs).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Where panicking inputs are saved (default: target/fuzz-crashes).
    #[arg(long)]
    crash_dir: Option<PathBuf>,
    /// List the targets and their seed counts.
    #[arg(long)]
    list: bool,
    /// Run one input through the (single) selected target, panic uncaught.
    #[arg(long)]
    replay: Option<PathBuf>,
    /// Regenerate the seed corpora in tests/fixtures/fuzz/.
    #[arg(long)]
    write_seeds: bool,
    /// Print the first distinct outcomes (error texts) of each target.
    #[arg(long)]
    outcomes: bool,
    /// Fail on an input that allocates more than this at once (MiB).
    #[arg(long)]
    max_alloc_mib: Option<usize>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    if args.write_seeds {
        let dir = workspace_root().join("tests/fixtures/fuzz");
        match farsight_fuzz::seeds::write(&dir) {
            Ok(counts) => {
                for (t, n) in counts {
                    println!("{t:<26} {n:>3} seeds");
                }
                return ExitCode::SUCCESS;
            }
            Err(e) => {
                eprintln!("farsight-fuzz: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    let selected: Vec<Target> = targets()
        .into_iter()
        .filter(|t| args.target.is_empty() || args.target.iter().any(|p| t.name.starts_with(p)))
        .collect();
    if selected.is_empty() {
        eprintln!(
            "farsight-fuzz: no target matches {:?}; targets: {}",
            args.target,
            targets()
                .iter()
                .map(|t| t.name)
                .collect::<Vec<_>>()
                .join(" ")
        );
        return ExitCode::FAILURE;
    }
    if let Some(file) = &args.replay {
        let [t] = selected.as_slice() else {
            eprintln!("farsight-fuzz: --replay needs exactly one --target");
            return ExitCode::FAILURE;
        };
        let input = match std::fs::read(file) {
            Ok(b) => b,
            Err(e) => {
                eprintln!("farsight-fuzz: {}: {e}", file.display());
                return ExitCode::FAILURE;
            }
        };
        println!("{}: {:?}", t.name, (t.run)(&input));
        return ExitCode::SUCCESS;
    }
    let mut loaded = Vec::new();
    for t in &selected {
        match t.load_seeds() {
            Ok(s) => loaded.push((*t, s.into_iter().map(|(_, b)| b).collect::<Vec<_>>())),
            Err(e) => {
                eprintln!("farsight-fuzz: {}: {e}", t.name);
                return ExitCode::FAILURE;
            }
        }
    }
    if args.list {
        for (t, s) in &loaded {
            println!(
                "{:<26} {:>3} seeds  {}",
                t.name,
                s.len(),
                t.seeds_dir().display()
            );
        }
        return ExitCode::SUCCESS;
    }
    let total = Duration::from_secs_f64(args.seconds.clamp(0.0, 1e9));
    let selected: Vec<Target> = loaded.iter().map(|(t, _)| *t).collect();
    let crash_dir = args.crash_dir.unwrap_or_else(default_crash_dir);
    println!(
        "farsight-fuzz: {} targets, {:.0} s in all (shared by weight), seed {}",
        loaded.len(),
        total.as_secs_f64(),
        args.seed
    );
    let mut stats = Vec::new();
    for ((t, seeds), share) in loaded.iter().zip(shares(&selected, total)) {
        let max_alloc = args.max_alloc_mib.map(|m| m << 20);
        let s = fuzz(t, seeds, share, args.seed, &crash_dir, max_alloc);
        println!(
            "  {:<26} {:>9} execs {:>4} panics",
            s.target, s.execs, s.panics
        );
        if args.outcomes {
            for o in &s.outcome_texts {
                println!("    {}", o.replace('\n', " / "));
            }
        }
        stats.push(s);
    }
    print!("\n{}", table(&stats));
    if stats.iter().any(|s| s.panics > 0 || s.oversized > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
