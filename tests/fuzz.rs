//! Fuzzing (issue 17, item 4): every fuzz target of `tools/fuzz` (images,
//! ROS CDR, ROS camera_info, MCAP, the wire messages of every topic kind,
//! every stage's config) runs from its committed seed corpus
//! (`tests/fixtures/fuzz/<target>/`) for its share of a total budget of
//! 180 s (or `FARSIGHT_FUZZ_SECONDS`), by weight: the richer formats
//! (MCAP, images) get more than the small fixed-size messages. The mutations are seeded (1, or
//! `FARSIGHT_FUZZ_SEED`): a slower machine runs a prefix of the inputs a
//! faster one runs. No input may panic (a panicking one is saved under
//! `target/fuzz-crashes/<target>/`; `farsight-fuzz --target T --replay FILE`
//! shows the panic), and every target must have run and accepted inputs,
//! so a target skipped or broken shows here.

use farsight_fuzz::{default_crash_dir, fuzz, shares, table, targets};
use std::time::Duration;

/// Measures each input's largest allocation (the table's "alloc MiB").
#[global_allocator]
static ALLOC: farsight_fuzz::MeasuringAlloc = farsight_fuzz::MeasuringAlloc;

/// Each target runs at least this many inputs, however busy the machine
/// (the slowest, MCAP, runs thousands a second on one core).
const MIN_EXECS: u64 = 200;

fn env_f64(name: &str, default: f64) -> f64 {
    match std::env::var(name) {
        Ok(v) => v.parse().unwrap_or_else(|e| panic!("{name}={v:?}: {e}")),
        Err(_) => default,
    }
}

#[test]
fn no_input_panics_any_target() {
    let total = env_f64("FARSIGHT_FUZZ_SECONDS", 180.0);
    let seed = env_f64("FARSIGHT_FUZZ_SEED", 1.0) as u64;
    // Off by default: the MCAP reader reserves what a chunk header says
    // (try_reserve, refused where it cannot be had), up to GiBs.
    let max_alloc = std::env::var("FARSIGHT_FUZZ_MAX_ALLOC_MIB").ok().map(|v| {
        v.parse::<usize>()
            .expect("FARSIGHT_FUZZ_MAX_ALLOC_MIB: MiB")
            << 20
    });
    let all = targets();
    println!(
        "fuzzing {} targets for {total} s in all (shared by weight), seed {seed}",
        all.len()
    );
    let crash_dir = default_crash_dir();
    let mut stats = Vec::new();
    for (t, share) in all.iter().zip(shares(&all, Duration::from_secs_f64(total))) {
        let seeds: Vec<Vec<u8>> = t
            .load_seeds()
            .unwrap_or_else(|e| panic!("{e}"))
            .into_iter()
            .map(|(_, b)| b)
            .collect();
        let s = fuzz(t, &seeds, share, seed, &crash_dir, max_alloc);
        println!(
            "  {:<26} {:>9} execs {:>4} panics",
            s.target, s.execs, s.panics
        );
        stats.push(s);
    }
    println!("\n{}", table(&stats));
    let mut failures = Vec::new();
    for s in &stats {
        for c in &s.crashes {
            failures.push(format!(
                "{}: {} (input saved: {}; farsight-fuzz --target {} --replay {} runs it)",
                s.target,
                c.message,
                c.path.display(),
                s.target,
                c.path.display()
            ));
        }
        if (s.panics > 0 || s.oversized > 0) && s.crashes.is_empty() {
            failures.push(format!("{}: {} panics", s.target, s.panics));
        }
        if s.execs < MIN_EXECS {
            failures.push(format!(
                "{}: only {} inputs run (at least {MIN_EXECS} expected)",
                s.target, s.execs
            ));
        }
        if s.accepted == 0 {
            failures.push(format!("{}: accepted no input, not even a seed", s.target));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
