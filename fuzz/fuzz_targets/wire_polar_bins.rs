#![no_main]
use std::sync::OnceLock;

static RUN: OnceLock<fn(&[u8]) -> farsight_fuzz::Verdict> = OnceLock::new();

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let run = RUN.get_or_init(|| farsight_fuzz::target("wire_polar_bins").expect("a farsight-fuzz target").run);
    let _ = run(data);
});
