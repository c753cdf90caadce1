//! # farsight-fuzz
//!
//! Fuzz targets for every input farsight parses from outside: PNG/JPEG
//! images, ROS 2 CDR images, ROS `camera_info` YAML, MCAP files, the wire
//! messages of every topic kind and every stage's config file. Each target
//! is a plain `fn(&[u8]) -> Verdict`: it runs what the stage does with such
//! an input and says whether the input was accepted; it must never panic.
//!
//! Two engines run the same targets:
//! - [`fuzz`]: a seeded mutation runner on the stable toolchain (bit flips,
//!   edge values, inserted, deleted and duplicated ranges, cuts, splices of
//!   two inputs, and for text targets number and punctuation tokens),
//!   started from the committed seed corpora under `tests/fixtures/fuzz/`.
//!   Inputs that end in an outcome not seen before (an error of another
//!   kind) join the pool it mutates. The test command runs it
//!   (`tests/fuzz.rs`), `farsight-fuzz` runs it for as long as asked.
//! - cargo-fuzz (libFuzzer, coverage-guided): `fuzz/` at the workspace
//!   root, one fuzz target per [`Target`].
//!
//! A panicking input is saved to `target/fuzz-crashes/<target>/<hash>`;
//! `farsight-fuzz --target NAME --replay FILE` runs it again with the
//! panic's backtrace.

pub mod mutate;
pub mod seeds;
pub mod targets;

use mutate::Rng;
use std::collections::HashSet;
use std::hash::{Hash, Hasher};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};
pub use targets::Verdict;

/// The largest single allocation since [`fuzz`] last reset it (bytes).
static LARGEST_ALLOC: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Remembers a granted allocation's size (a refused one, which the caller
/// handles as `try_reserve` does, is not counted).
fn note_alloc(ptr: *mut u8, size: usize) -> *mut u8 {
    if !ptr.is_null() {
        LARGEST_ALLOC.fetch_max(size, std::sync::atomic::Ordering::Relaxed);
    }
    ptr
}

/// The system allocator, remembering the largest single allocation, so
/// [`fuzz`] sees an input that makes a parser reserve gigabytes from a
/// length field (what libFuzzer reports as out-of-memory; under Linux's
/// overcommit such a reservation may go unnoticed until a smaller machine
/// aborts on it). Install it in the binary that fuzzes:
/// `#[global_allocator] static A: farsight_fuzz::MeasuringAlloc = farsight_fuzz::MeasuringAlloc;`
/// Without it the "max alloc" figures stay 0.
pub struct MeasuringAlloc;

// SAFETY: every call is passed on to `System` unchanged.
unsafe impl std::alloc::GlobalAlloc for MeasuringAlloc {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        note_alloc(unsafe { std::alloc::System.alloc(layout) }, layout.size())
    }
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        note_alloc(
            unsafe { std::alloc::System.alloc_zeroed(layout) },
            layout.size(),
        )
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        note_alloc(
            unsafe { std::alloc::System.realloc(ptr, layout, new_size) },
            new_size,
        )
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: the caller's contract, passed on.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
}

/// What a target runs on one input.
pub type RunFn = fn(&[u8]) -> Verdict;

/// One fuzz target.
#[derive(Clone, Copy)]
pub struct Target {
    pub name: &'static str,
    pub run: RunFn,
    /// Text input (TOML, YAML): token mutations as well as byte ones.
    pub text: bool,
    /// Its share of a total budget, relative to the others' (the richer
    /// formats get more than the small fixed-size messages).
    pub weight: u32,
}

impl std::fmt::Debug for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

impl Target {
    /// The committed seed corpus: `tests/fixtures/fuzz/<name>/`.
    pub fn seeds_dir(&self) -> PathBuf {
        workspace_root().join("tests/fixtures/fuzz").join(self.name)
    }

    /// The seed corpus's files, by name. A target without seeds is an error:
    /// it would fuzz nothing real.
    pub fn load_seeds(&self) -> Result<Vec<(String, Vec<u8>)>, String> {
        let dir = self.seeds_dir();
        let mut out = Vec::new();
        let entries = std::fs::read_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        for e in entries {
            let e = e.map_err(|e| format!("{}: {e}", dir.display()))?;
            if e.file_type().map_err(|e| e.to_string())?.is_file() {
                let bytes = std::fs::read(e.path())
                    .map_err(|err| format!("{}: {err}", e.path().display()))?;
                out.push((e.file_name().to_string_lossy().into_owned(), bytes));
            }
        }
        out.sort();
        if out.is_empty() {
            return Err(format!(
                "{}: no seeds (farsight-fuzz --write-seeds makes them)",
                dir.display()
            ));
        }
        Ok(out)
    }
}

/// The workspace's root (this crate is `tools/fuzz`).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Where panicking inputs go: `target/fuzz-crashes/` (or
/// `$CARGO_TARGET_DIR/fuzz-crashes/`).
pub fn default_crash_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"))
        .join("fuzz-crashes")
}

/// Every target, in the order they run.
pub fn targets() -> Vec<Target> {
    use targets as t;
    let mut out = vec![
        Target {
            name: "image",
            run: t::image,
            text: false,
            weight: 3,
        },
        Target {
            name: "ros_cdr",
            run: t::ros_cdr,
            text: false,
            weight: 2,
        },
        Target {
            name: "ros_camera_info",
            run: t::ros_camera_info,
            text: true,
            weight: 1,
        },
        Target {
            name: "mcap",
            run: t::mcap,
            text: false,
            weight: 6,
        },
    ];
    for (kind, _) in t::KINDS {
        let (name, run) = t::wire_target(kind);
        out.push(Target {
            name,
            run,
            text: false,
            weight: if kind == farsight_interfaces::topics::TopicKind::Image {
                2
            } else {
                1
            },
        });
    }
    let configs: [(&'static str, RunFn); 11] = [
        ("config_camera_ingest", t::config_camera_ingest),
        ("config_inference", t::config_inference),
        ("config_model", t::config_model),
        ("config_class_table", t::config_class_table),
        ("config_bin_projection", t::config_bin_projection),
        ("config_costmap_fusion", t::config_costmap_fusion),
        ("config_subgoal_selection", t::config_subgoal_selection),
        ("config_hip_library", t::config_hip_library),
        ("config_velocity_servoing", t::config_velocity_servoing),
        ("config_command_mux", t::config_command_mux),
        ("config_bridge", t::config_bridge),
    ];
    out.extend(configs.into_iter().map(|(name, run)| Target {
        name,
        run,
        text: true,
        weight: 1,
    }));
    out
}

/// Each target's share of `total`, by weight.
pub fn shares(targets: &[Target], total: Duration) -> Vec<Duration> {
    let sum: u32 = targets.iter().map(|t| t.weight.max(1)).sum();
    targets
        .iter()
        .map(|t| total.mul_f64(f64::from(t.weight.max(1)) / f64::from(sum.max(1))))
        .collect()
}

/// The target called `name`.
pub fn target(name: &str) -> Option<Target> {
    targets().into_iter().find(|t| t.name == name)
}

/// A panicking input, saved.
#[derive(Debug, Clone)]
pub struct Crash {
    pub path: PathBuf,
    /// The panic's message and where it was raised.
    pub message: String,
}

/// What one target's run did.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    pub target: String,
    pub seeds: usize,
    pub execs: u64,
    /// Inputs the target accepted.
    pub accepted: u64,
    /// Distinct outcomes (accepted, or refused for a distinct reason).
    pub outcomes: usize,
    pub panics: u64,
    /// One saved input per distinct panic (or oversized allocation).
    pub crashes: Vec<Crash>,
    pub elapsed: Duration,
    /// The slowest single input.
    pub slowest: Duration,
    /// The largest single allocation one input made (0 without
    /// [`MeasuringAlloc`]), and that input, saved when over 256 MiB.
    pub max_alloc: usize,
    pub max_alloc_input: Option<PathBuf>,
    /// Inputs that allocated more than the limit at once (failures).
    pub oversized: u64,
    /// The first distinct outcomes' texts (up to 200), for a look at
    /// where the inputs end (`farsight-fuzz --outcomes`).
    pub outcome_texts: Vec<String>,
}

impl Stats {
    pub fn execs_per_s(&self) -> f64 {
        self.execs as f64 / self.elapsed.as_secs_f64().max(1e-9)
    }
}

thread_local! {
    static LAST_PANIC: std::cell::RefCell<Option<String>> = const { std::cell::RefCell::new(None) };
}

/// One fuzzing run at a time in a process: the panic hook is global.
static RUNNING: Mutex<()> = Mutex::new(());

/// Silences panic messages while installed (they are counted and saved
/// instead) and restores the previous hook when dropped.
type PanicHook = Box<dyn Fn(&std::panic::PanicHookInfo<'_>) + Sync + Send + 'static>;

struct QuietPanics {
    previous: Option<PanicHook>,
}

impl QuietPanics {
    fn install() -> Self {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(|info| {
            let msg = info
                .payload()
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| info.payload().downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".into());
            let at = info
                .location()
                .map(|l| format!("{}:{}", l.file(), l.line()))
                .unwrap_or_default();
            LAST_PANIC.with(|p| *p.borrow_mut() = Some(format!("{msg} at {at}")));
        }));
        Self {
            previous: Some(previous),
        }
    }
}

impl Drop for QuietPanics {
    fn drop(&mut self) {
        if let Some(p) = self.previous.take() {
            std::panic::set_hook(p);
        }
    }
}

fn hash_of(bytes: &[u8]) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    bytes.hash(&mut h);
    h.finish()
}

/// An outcome's signature: accepted, or the words of the error: the
/// all-lowercase words of its first and last lines outside quotes (what
/// an input holds, offsets, sizes, hex and quoted bytes differ between
/// inputs that take one path through the code; the words name the path).
fn outcome(v: &Verdict) -> u64 {
    let Err(e) = v else {
        return 0;
    };
    let mut h = std::collections::hash_map::DefaultHasher::new();
    let lines = [e.lines().next(), e.lines().last()];
    for line in lines.into_iter().flatten() {
        let mut quoted = None;
        let mut escaped = false;
        let mut unquoted = String::new();
        for c in line.chars() {
            match quoted {
                _ if escaped => escaped = false,
                Some(_) if c == '\\' => escaped = true,
                Some(q) if c == q => quoted = None,
                Some(_) => {}
                None if matches!(c, '"' | '`' | '[') => {
                    quoted = Some(if c == '[' { ']' } else { c })
                }
                None => unquoted.push(c),
            }
        }
        for word in unquoted
            .split_whitespace()
            .map(|w| w.trim_matches(|c: char| c.is_ascii_punctuation()))
            .filter(|w| w.len() >= 2 && w.bytes().all(|b| b.is_ascii_lowercase()))
            .take(24)
        {
            word.hash(&mut h);
        }
    }
    h.finish() | 1
}

/// Runs `target` on one input, catching a panic: `Ok(verdict)` or
/// `Err(panic message)`.
pub fn run_one(target: &Target, input: &[u8]) -> Result<Verdict, String> {
    catch_unwind(AssertUnwindSafe(|| (target.run)(input))).map_err(|_| {
        LAST_PANIC
            .with(|p| p.borrow_mut().take())
            .unwrap_or_else(|| "(panic message not captured)".into())
    })
}

/// Fuzzes `target` for `budget`, from `seeds`, deterministically from
/// `seed` (but for how many inputs fit the budget). Each seed runs first as
/// it is; then mutations of the pool (the seeds plus inputs that ended in
/// a new outcome). Each panicking input with a new message is saved under
/// `crash_dir/<target>/`; so is one input that allocates more than
/// `max_alloc` bytes at once (with [`MeasuringAlloc`] installed).
pub fn fuzz(
    target: &Target,
    seeds: &[Vec<u8>],
    budget: Duration,
    seed: u64,
    crash_dir: &Path,
    max_alloc: Option<usize>,
) -> Stats {
    let _one = RUNNING.lock().unwrap_or_else(|e| e.into_inner());
    let _quiet = QuietPanics::install();
    let mut rng = Rng::new(seed ^ hash_of(target.name.as_bytes()));
    let mut stats = Stats {
        target: target.name.to_string(),
        seeds: seeds.len(),
        ..Default::default()
    };
    let mut pool: Vec<Vec<u8>> = seeds.to_vec();
    let mut seen: HashSet<u64> = HashSet::new();
    let mut failures_seen: HashSet<String> = HashSet::new();
    let mut largest_input: Option<Vec<u8>> = None;
    let start = Instant::now();
    let mut next_seed = 0;
    loop {
        let input = if next_seed < seeds.len() {
            next_seed += 1;
            seeds[next_seed - 1].clone()
        } else {
            if start.elapsed() >= budget {
                break;
            }
            if pool.is_empty() {
                break;
            }
            // Half the time a committed seed, else anything in the pool.
            let from = if rng.chance(2) && !seeds.is_empty() {
                &seeds[rng.below(seeds.len())]
            } else {
                &pool[rng.below(pool.len())]
            };
            let mut input = from.clone();
            let others: Vec<&[u8]> = (0..2)
                .filter(|_| !pool.is_empty())
                .map(|_| pool[rng.below(pool.len())].as_slice())
                .collect();
            for _ in 0..1 << rng.below(4) {
                if target.text && rng.chance(2) {
                    mutate::mutate_text(&mut rng, &mut input, &others);
                } else {
                    mutate::mutate_bytes(&mut rng, &mut input, &others);
                }
            }
            input
        };
        let t0 = Instant::now();
        LARGEST_ALLOC.store(0, std::sync::atomic::Ordering::Relaxed);
        let result = run_one(target, &input);
        let allocated = LARGEST_ALLOC.load(std::sync::atomic::Ordering::Relaxed);
        stats.slowest = stats.slowest.max(t0.elapsed());
        stats.execs += 1;
        if allocated > stats.max_alloc {
            stats.max_alloc = allocated;
            largest_input = Some(input.clone());
        }
        let failure = match result {
            Err(panic) => {
                stats.panics += 1;
                Some(panic)
            }
            Ok(_) if max_alloc.is_some_and(|limit| allocated > limit) => {
                stats.oversized += 1;
                Some(format!(
                    "allocated {} MiB at once (limit {} MiB)",
                    allocated >> 20,
                    max_alloc.unwrap_or(0) >> 20
                ))
            }
            Ok(verdict) => {
                stats.accepted += u64::from(verdict.is_ok());
                if seen.insert(outcome(&verdict)) {
                    if stats.outcome_texts.len() < 200 {
                        stats
                            .outcome_texts
                            .push(verdict.err().unwrap_or_else(|| "accepted".into()));
                    }
                    if pool.len() < 4096 {
                        pool.push(input.clone());
                    }
                }
                None
            }
        };
        if let Some(message) = failure {
            let key: String = message.chars().filter(|c| !c.is_ascii_digit()).collect();
            if failures_seen.insert(key) {
                let dir = crash_dir.join(target.name);
                let path = dir.join(format!("{:016x}", hash_of(&input)));
                let saved =
                    std::fs::create_dir_all(&dir).and_then(|()| std::fs::write(&path, &input));
                stats.crashes.push(Crash {
                    path: if saved.is_ok() {
                        path
                    } else {
                        PathBuf::from("(not saved)")
                    },
                    message,
                });
            }
        }
    }
    stats.outcomes = seen.len();
    stats.elapsed = start.elapsed();
    if let Some(input) = largest_input.filter(|_| stats.max_alloc > 256 << 20) {
        let dir = crash_dir.join(target.name);
        let path = dir.join(format!("big-alloc-{:016x}", hash_of(&input)));
        if std::fs::create_dir_all(&dir)
            .and_then(|()| std::fs::write(&path, &input))
            .is_ok()
        {
            stats.max_alloc_input = Some(path);
        }
    }
    stats
}

/// The table of a run: target, seeds, executions, executions per second,
/// outcomes, slowest input, panics; then each saved crash.
pub fn table(stats: &[Stats]) -> String {
    let mut out = format!(
        "{:<26} {:>5} {:>9} {:>9} {:>8} {:>8} {:>10} {:>9} {:>6}\n",
        "target",
        "seeds",
        "execs",
        "execs/s",
        "accepted",
        "outcomes",
        "slowest ms",
        "alloc MiB",
        "panics"
    );
    for s in stats {
        out += &format!(
            "{:<26} {:>5} {:>9} {:>9.0} {:>8} {:>8} {:>10.1} {:>9.1} {:>6}\n",
            s.target,
            s.seeds,
            s.execs,
            s.execs_per_s(),
            s.accepted,
            s.outcomes,
            s.slowest.as_secs_f64() * 1e3,
            s.max_alloc as f64 / (1 << 20) as f64,
            s.panics
        );
    }
    let execs: u64 = stats.iter().map(|s| s.execs).sum();
    let panics: u64 = stats.iter().map(|s| s.panics).sum();
    out += &format!(
        "{:<26} {:>5} {execs:>9} {:>9} {:>8} {:>8} {:>10} {:>9} {panics:>6}\n",
        "total",
        stats.iter().map(|s| s.seeds).sum::<usize>(),
        "",
        "",
        "",
        "",
        ""
    );
    for s in stats {
        for c in &s.crashes {
            out += &format!(
                "FAILED {}: {} (input: {})\n",
                s.target,
                c.message,
                c.path.display()
            );
        }
        if let Some(p) = &s.max_alloc_input {
            out += &format!(
                "note {}: one input allocated {} MiB at once (input: {})\n",
                s.target,
                s.max_alloc >> 20,
                p.display()
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toy(bytes: &[u8]) -> Verdict {
        if bytes.len() > 3 && bytes[3] == b'!' {
            panic!("bang at {}", bytes.len());
        }
        if bytes.first() == Some(&b'a') {
            Ok(())
        } else {
            Err(format!("not a: {} bytes", bytes.len()))
        }
    }

    #[test]
    fn a_panicking_input_is_counted_and_saved_and_the_hook_restored() {
        let t = Target {
            name: "toy",
            run: toy,
            text: false,
            weight: 1,
        };
        let dir = std::env::temp_dir().join(format!("farsight-fuzz-test-{}", std::process::id()));
        let s = fuzz(
            &t,
            &[b"abc".to_vec(), b"abcd".to_vec()],
            Duration::from_millis(300),
            1,
            &dir,
            None,
        );
        assert!(s.execs > 100, "{s:?}");
        assert!(s.accepted > 0 && s.outcomes >= 2, "{s:?}");
        assert!(s.panics > 0, "{s:?}");
        let c = &s.crashes[0];
        assert!(c.message.starts_with("bang at "), "{}", c.message);
        assert!(c.message.contains("lib.rs:"), "{}", c.message);
        let input = std::fs::read(&c.path).unwrap();
        assert_eq!(input[3], b'!');
        assert!(catch_unwind(|| toy(&input)).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn targets_have_unique_names_and_every_topic_kind_has_one() {
        let t = targets();
        let names: HashSet<_> = t.iter().map(|t| t.name).collect();
        assert_eq!(names.len(), t.len());
        for (kind, _) in targets::KINDS {
            assert!(names.contains(targets::wire_target(kind).0));
        }
    }

    /// `fuzz/` (cargo-fuzz) has one fuzz target per target, calling it.
    #[test]
    fn cargo_fuzz_has_every_target() {
        let dir = workspace_root().join("fuzz");
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap();
        for t in targets() {
            assert!(
                manifest.contains(&format!("name = \"{}\"", t.name)),
                "fuzz/Cargo.toml has no [[bin]] {}",
                t.name
            );
            let path = dir.join(format!("fuzz_targets/{}.rs", t.name));
            let src = std::fs::read_to_string(&path)
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(
                src.contains(&format!("target(\"{}\")", t.name)),
                "{}",
                path.display()
            );
        }
    }

    /// Each committed seed is a valid sample its target accepts (the files
    /// named `bad-*` are known-bad inputs, kept as seeds and refused).
    #[test]
    fn every_seed_is_accepted_and_every_bad_seed_refused() {
        let mut failures = Vec::new();
        for t in targets() {
            let seeds = t.load_seeds().unwrap();
            for (name, bytes) in seeds {
                let got = (t.run)(&bytes);
                let bad = name.starts_with("bad-");
                if got.is_ok() == bad {
                    failures.push(format!("{}/{name}: {got:?}", t.name));
                }
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
    }
}
