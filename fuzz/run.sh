#!/usr/bin/env bash
# The long coverage-guided run: cargo-fuzz (libFuzzer) on each farsight-fuzz
# target, from its committed seeds (tests/fixtures/fuzz/TARGET) and what
# earlier runs found (fuzz/corpus/TARGET, kept between runs).
#
#   fuzz/run.sh [SECONDS_PER_TARGET] [TARGET...]   # default: 3600 s, every target
#
# Stops at the first crash (libFuzzer writes it to fuzz/artifacts/TARGET/;
# `farsight-fuzz --target TARGET --replay FILE` runs it again on stable).
# cargo-fuzz needs nightly flags: RUSTC_BOOTSTRAP=1 lets the stable
# toolchain take them (or use `cargo +nightly fuzz`). More libFuzzer flags
# go in LIBFUZZER_ARGS, e.g. LIBFUZZER_ARGS=-malloc_limit_mb=16384 (by
# default libFuzzer stops at a single allocation over 2 GiB).
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-3600}
shift || true
if [ $# -gt 0 ]; then targets=("$@"); else mapfile -t targets < <(ls tests/fixtures/fuzz); fi
# A refused allocation returns null, as in production (try_reserve), not
# an ASan abort.
export ASAN_OPTIONS=${ASAN_OPTIONS:-allocator_may_return_null=1}
command -v cargo-fuzz >/dev/null || cargo install --locked cargo-fuzz@0.13.2
for t in "${targets[@]}"; do
    mkdir -p "fuzz/corpus/$t"
    RUSTC_BOOTSTRAP=1 cargo fuzz run "$t" "fuzz/corpus/$t" "tests/fixtures/fuzz/$t" -- \
        -max_total_time="$secs" -print_final_stats=1 ${LIBFUZZER_ARGS:-}
done
