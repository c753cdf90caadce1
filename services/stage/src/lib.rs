//! # farsight-stage
//!
//! The skeleton every farsight stage binary runs on, so each `main` is a thin
//! loop around its library code:
//!
//! - [`StageArgs`]: `--config <file.toml>`, `--log-format text|json`;
//! - [`load_config`]: TOML into a typed config, then [`Validate`]: each
//!   numeric key's declared [`Range`], then the rules between keys; every
//!   error names the file, key, value and what was expected;
//! - [`init_tracing`]: `RUST_LOG`-style filters, JSON lines for journald;
//! - [`StageInputs`]: required and optional inputs judged on capture time,
//!   and the stamp outputs carry;
//! - [`Health`]: the stage's [`StageHealth`] message, published at a fixed rate;
//!   its tick also pings systemd's watchdog ([`watchdog`]);
//! - shutdown: [`farsight_interfaces::transport::ipc::wait_loop`] returns
//!   `Terminated` on SIGTERM/SIGINT, and the stage publishes a last
//!   `stopping` health message before it exits. A freeze (SIGSTOP, then
//!   SIGCONT) is not a shutdown: the loop waits on.
//!
//! ```no_run
//! use farsight_stage::{load_config, StageArgs, Validate, Health, Range, Ranges};
//! use farsight_interfaces::{clock::{Clock, WallClock}, transport::ipc::{self, Bus, Wake}};
//! use serde::Deserialize;
//! use std::ops::ControlFlow;
//!
//! #[derive(Deserialize, Default)]
//! #[serde(deny_unknown_fields, default)]
//! struct Config { rate_hz: f64 }
//! impl Validate for Config {
//!     fn ranges(&self, r: &mut Ranges) {
//!         r.key("rate_hz", self.rate_hz, Range::above_to(0.0, 1000.0).unit("Hz"));
//!     }
//! }
//!
//! let args = StageArgs::parse("example")?;
//! farsight_stage::init_tracing(args.log_format);
//! let config: Config = load_config(args.config.as_deref())?;
//! let bus = Bus::open("example")?;
//! let mut health = Health::new(&bus, "example", 1.0)?;
//! ipc::wait_loop(&[], Some(std::time::Duration::from_millis(100)), |_wake| {
//!     health.tick(WallClock.now_ns());
//!     ControlFlow::Continue(())
//! })?;
//! health.stopping(WallClock.now_ns());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod camera_models;
pub mod executor;
pub mod inputs;
pub mod io;
pub mod ranges;
pub mod runtime;
pub mod watchdog;

pub use camera_models::CameraModels;
pub use inputs::{Freshness, InputId, Need, StageInputs};
pub use io::{DeclaresTopics, Io};
pub use ranges::{Range, Ranges};
pub use runtime::{Inbox, Outbox, Ports, Sink, Stage, StageEnv, StageKind, Step, Wake};

use farsight_interfaces::fixed::FixedStr;
use farsight_interfaces::msg::{HealthState, StageHealth, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, Publisher};
use farsight_interfaces::transport::TransportError;
use serde::de::DeserializeOwned;
use std::fmt::Display;
use std::path::{Path, PathBuf};

/// A config that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("config {path}: {detail}")]
    Parse { path: String, detail: String },
    #[error("config key `{key}` = {value}: expected {expected}")]
    Invalid {
        key: String,
        value: String,
        expected: String,
    },
}

impl ConfigError {
    pub fn invalid(
        key: impl Into<String>,
        value: impl Display,
        expected: impl Into<String>,
    ) -> Self {
        Self::Invalid {
            key: key.into(),
            value: value.to_string(),
            expected: expected.into(),
        }
    }

    /// `Ok(())` if `ok`, else an [`ConfigError::Invalid`] naming the key and value.
    pub fn check(ok: bool, key: &str, value: impl Display, expected: &str) -> Result<(), Self> {
        if ok {
            Ok(())
        } else {
            Err(Self::invalid(key, value, expected))
        }
    }
}

/// Declares the ranges of an optional ENU anchor (`anchor_latitude_deg`,
/// `anchor_longitude_deg`); [`check_anchor`] checks that both or neither are set.
pub fn anchor_ranges(r: &mut Ranges, latitude_deg: Option<f64>, longitude_deg: Option<f64>) {
    r.optional(
        "anchor_latitude_deg",
        latitude_deg,
        Range::between(-90.0, 90.0).unit("deg"),
    );
    r.optional(
        "anchor_longitude_deg",
        longitude_deg,
        Range::between(-180.0, 180.0).unit("deg"),
    );
}

/// Checks an optional ENU anchor given as `anchor_latitude_deg` and
/// `anchor_longitude_deg`: both or neither, each in range.
pub fn check_anchor(
    latitude_deg: Option<f64>,
    longitude_deg: Option<f64>,
) -> Result<(), ConfigError> {
    match (latitude_deg, longitude_deg) {
        (None, None) => Ok(()),
        (Some(lat), Some(lon)) => farsight_interfaces::geo::GeoPoint::new(lat, lon, 0.0)
            .map(|_| ())
            .map_err(|e| {
                ConfigError::invalid(
                    format!("anchor_{}", e.field),
                    e.value,
                    format!("[{}, {}] degrees", e.min, e.max),
                )
            }),
        (lat, lon) => Err(ConfigError::invalid(
            "anchor_latitude_deg/anchor_longitude_deg",
            format!("{lat:?}/{lon:?}"),
            "both or neither",
        )),
    }
}

/// Checks a config's values after parsing.
pub trait Validate {
    /// Declares the range of every numeric key ([`Ranges::key`]); nested
    /// tables through [`Ranges::nested`]. Checked first, at load; the config
    /// sweep test tries values outside each declared range.
    fn ranges(&self, _r: &mut Ranges) {}

    /// What a range cannot say: names, choices, keys that depend on each
    /// other. Runs after the ranges have passed; a parent calls its nested
    /// tables' rules.
    fn check_rules(&self) -> Result<(), ConfigError> {
        Ok(())
    }

    /// Ranges, then rules.
    fn validate(&self) -> Result<(), ConfigError> {
        Ranges::of(self).check()?;
        self.check_rules()
    }
}

/// Parses TOML text into `T` and validates it; `origin` names the source in errors.
/// A `nan`, `inf` or `-inf` anywhere is refused, naming its key, except
/// `inf` in a cost (a key ending in `cost_s_per_m`), which means lethal.
pub fn parse_config<T: DeserializeOwned + Validate>(
    text: &str,
    origin: &str,
) -> Result<T, ConfigError> {
    let config: T = toml::from_str(text).map_err(|e| ConfigError::Parse {
        path: origin.to_string(),
        detail: e.to_string().trim_end().to_string(),
    })?;
    // Declared ranges first: their errors name the range. A non-finite
    // value in a key no range covers is still refused before the rules see it.
    Ranges::of(&config).check()?;
    if let Ok(table) = toml::from_str::<toml::Table>(text) {
        refuse_non_finite(&toml::Value::Table(table), "")?;
    }
    config.check_rules()?;
    Ok(config)
}

const NON_FINITE: &str =
    "a finite number (nan and inf mean nothing here; only a cost_s_per_m may be inf: lethal)";

/// The first non-finite float under `value`, as an error naming its key
/// (`servo.k_linear`, `cameras[0].rate_hz`).
fn refuse_non_finite(value: &toml::Value, key: &str) -> Result<(), ConfigError> {
    let lethal_cost = |f: f64| f == f64::INFINITY && key.ends_with("cost_s_per_m");
    match value {
        toml::Value::Float(f) if !f.is_finite() && !lethal_cost(*f) => {
            Err(ConfigError::invalid(key, f, NON_FINITE))
        }
        toml::Value::Table(t) => t.iter().try_for_each(|(k, v)| {
            let key = if key.is_empty() {
                k.clone()
            } else {
                format!("{key}.{k}")
            };
            refuse_non_finite(v, &key)
        }),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .try_for_each(|(i, v)| refuse_non_finite(v, &format!("{key}[{i}]"))),
        _ => Ok(()),
    }
}

/// Loads and validates a config file that must exist.
pub fn load_config_file<T: DeserializeOwned + Validate>(path: &Path) -> Result<T, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_config(&text, &path.display().to_string())
}

/// Loads and validates a config file; with no path, the documented defaults
/// (`T::default()`), still validated.
pub fn load_config<T: DeserializeOwned + Validate + Default>(
    path: Option<&Path>,
) -> Result<T, ConfigError> {
    match path {
        None => {
            let config = T::default();
            config.validate()?;
            Ok(config)
        }
        Some(p) => load_config_file(p),
    }
}

/// Where a stage's "now" comes from (its config's `clock` key).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClockSource {
    /// The system clock; rate-driven outputs go out at their configured rates.
    #[default]
    Wall,
    /// The newest capture time among the stage's inputs, and one output per
    /// new input instead of rates: the same inputs give the same outputs
    /// however fast the machine is (lock-step simulation, replays). Never on
    /// a robot: with no input, time stands still and nothing goes stale.
    Stamps,
}

/// How log lines are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LogFormat {
    /// Human-readable lines on stderr.
    #[default]
    Text,
    /// One JSON object per line, for journald and log shippers.
    Json,
}

/// The command line every stage accepts.
#[derive(Debug, Clone, Default)]
pub struct StageArgs {
    /// `--config <file.toml>`; without it the stage runs on its documented defaults.
    pub config: Option<PathBuf>,
    /// `--log-format text|json` (or `FARSIGHT_LOG_FORMAT`).
    pub log_format: LogFormat,
    /// `--instance NAME`: this instance's name in the graph (its health
    /// topic `health/<NAME>`, its `NAME ready` line, its rows in `farsight
    /// inspect`), so a stage can run more than once (four cameras, four
    /// inference instances). Default: the stage's own name.
    pub instance: String,
    /// `--base-dir DIR`: relative paths in the config resolve against DIR
    /// instead of the config file's folder (`farsight run` passes the graph
    /// file's folder for a config written inline in the graph).
    pub base_dir: Option<PathBuf>,
}

/// A command line that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ArgsError(String);

impl StageArgs {
    /// Parses the process arguments; `--help` prints usage and exits.
    pub fn parse(stage: &str) -> Result<Self, ArgsError> {
        Self::parse_from(stage, std::env::args().skip(1))
    }

    pub fn parse_from(
        stage: &str,
        args: impl IntoIterator<Item = String>,
    ) -> Result<Self, ArgsError> {
        let mut out = StageArgs {
            log_format: match std::env::var("FARSIGHT_LOG_FORMAT").as_deref() {
                Ok("json") => LogFormat::Json,
                _ => LogFormat::Text,
            },
            instance: stage.to_string(),
            ..Default::default()
        };
        let mut it = args.into_iter();
        while let Some(a) = it.next() {
            match a.as_str() {
                "--config" | "-c" => {
                    let v = it
                        .next()
                        .ok_or_else(|| ArgsError("--config needs a file path".into()))?;
                    out.config = Some(PathBuf::from(v));
                }
                "--instance" => {
                    let v = it
                        .next()
                        .ok_or_else(|| ArgsError("--instance needs a name".into()))?;
                    topics::validate_name(&v)
                        .map_err(|e| ArgsError(format!("--instance {v:?}: {}", e.why)))?;
                    out.instance = v;
                }
                "--base-dir" => {
                    let v = it
                        .next()
                        .ok_or_else(|| ArgsError("--base-dir needs a folder".into()))?;
                    out.base_dir = Some(PathBuf::from(v));
                }
                "--log-format" => {
                    out.log_format = match it.next().as_deref() {
                        Some("text") => LogFormat::Text,
                        Some("json") => LogFormat::Json,
                        other => {
                            return Err(ArgsError(format!(
                                "--log-format {other:?}: expected text or json"
                            )))
                        }
                    }
                }
                "--help" | "-h" => {
                    println!(
                        "farsight-{stage}\n\nUSAGE: farsight-{stage} [--config FILE.toml] [--instance NAME] [--base-dir DIR] [--log-format text|json]\n\n\
                         Without --config the documented defaults are used.\n\
                         --instance names this instance (health/<NAME>); default: {stage}.\n\
                         Logging: RUST_LOG (e.g. info,farsight=debug). Shared memory namespace: FARSIGHT_IPC_PREFIX."
                    );
                    std::process::exit(0);
                }
                other => {
                    return Err(ArgsError(format!(
                        "unexpected argument {other:?} (try --help)"
                    )))
                }
            }
        }
        Ok(out)
    }

    /// Directory that relative paths in the config are resolved against:
    /// `--base-dir`, else the config file's folder, else `.`.
    pub fn config_dir(&self) -> PathBuf {
        if let Some(dir) = &self.base_dir {
            return dir.clone();
        }
        self.config
            .as_deref()
            .and_then(Path::parent)
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."))
    }
}

/// Sets up logging once: `RUST_LOG` filter (default `info`, with zenoh and
/// ONNX Runtime at `warn`: ORT logs every arena allocation at info), text
/// or JSON.
pub fn init_tracing(format: LogFormat) {
    init_tracing_with(
        format,
        "info,zenoh=warn,zenoh_transport=warn,zenoh_link_tcp=warn,ort=warn",
    );
}

/// [`init_tracing`] with another filter where `RUST_LOG` is unset (a tool
/// that runs stages in its own process, quieter than a stage).
pub fn init_tracing_with(format: LogFormat, default_filter: &str) {
    use tracing_subscriber::EnvFilter;
    let filter =
        EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default_filter));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = match format {
        LogFormat::Text => builder.try_init(),
        LogFormat::Json => builder.json().try_init(),
    };
}

/// The `main` of a stage: runs `run`, and on error logs it, prints it to stderr
/// (visible even before logging is set up) and exits with status 1.
/// Errors print in their alternate form, which for `anyhow` includes the causes.
pub fn run_main<E: Display>(stage: &str, run: impl FnOnce() -> Result<(), E>) {
    keep_freed_memory();
    if let Err(e) = run() {
        tracing::error!("{e:#}");
        eprintln!("farsight-{stage}: {e:#}");
        std::process::exit(1);
    }
}

/// Keeps the memory a stage frees for its next step instead of handing it
/// back to the kernel. A step's large buffers (a costmap layer, an image, a
/// few hundred kilobytes to megabytes) are over glibc's default mmap
/// threshold at first and, once that adapts, freed at the heap's top past
/// its trim threshold: either way each frame's buffers came as fresh pages
/// from the kernel, zeroed page by page on first touch, and went back
/// after. A sixth of costmap fusion's time on the FITAM chain went to those
/// page faults. The usual real-time Linux setting: the heap grows to the
/// stage's working set once and stays.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        /// glibc's largest mmap threshold on 64-bit (32 MiB): anything
        /// bigger is still mapped on its own and returned when freed.
        const MMAP_THRESHOLD_BYTES: libc::c_int = 32 << 20;
        /// Free memory at the heap's top kept before trimming.
        const TRIM_THRESHOLD_BYTES: libc::c_int = 128 << 20;
        // SAFETY: mallopt only sets allocator parameters; called before
        // the stage starts its threads.
        let set = unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
        };
        if !set {
            // Before logging is set up: straight to the journal.
            eprintln!("mallopt refused the heap thresholds; large buffers are mapped per step");
        }
    }
}

/// Tells launchers and tests the stage is set up: prints `<stage> ready` on
/// stdout (logs go to stderr), logs it and tells systemd (`READY=1`).
pub fn announce_ready(stage: &str) {
    use std::io::Write;
    tracing::info!("{stage} ready");
    watchdog::notify_ready();
    let mut out = std::io::stdout();
    let _ = writeln!(out, "{stage} ready");
    let _ = out.flush();
}

/// A stage's health as plain data: its state and reason, and the counts of
/// inputs, outputs and drops. A stage's step updates it; whoever runs the
/// stage ([`Health`] in a process, the in-process executor) sends it.
#[derive(Debug, Clone)]
pub struct HealthReport {
    msg: StageHealth,
    reason_logged: Option<std::time::Instant>,
}

impl HealthReport {
    pub fn new(instance: &str) -> Self {
        Self {
            msg: StageHealth {
                stage: FixedStr::truncated(instance),
                state: HealthState::STARTING,
                pid: std::process::id(),
                ..Default::default()
            },
            reason_logged: None,
        }
    }

    /// Sets the state; a change of state is logged and published at the next
    /// tick. A new reason in the same state (an input's age, counting up
    /// while it is stale) goes out with the next periodic report and is
    /// logged at most once a second, so a stale stage does not flood the
    /// journal.
    pub fn set(&mut self, state: HealthState, reason: &str) {
        let state_changed = self.msg.state != state;
        let reason_changed = self.msg.reason.as_str() != reason;
        let quiet = self
            .reason_logged
            .is_some_and(|t| t.elapsed() < std::time::Duration::from_secs(1));
        if state_changed || (reason_changed && !quiet) {
            if state == HealthState::OK {
                tracing::info!(%state, "health");
            } else {
                tracing::warn!(%state, reason, "health");
            }
            self.reason_logged = Some(std::time::Instant::now());
        }
        self.msg.state = state;
        self.msg.reason = FixedStr::truncated(reason);
    }

    pub fn state(&self) -> HealthState {
        self.msg.state
    }

    /// Counts an input message taken in.
    pub fn input(&mut self) {
        self.msg.messages_in += 1;
    }

    /// Counts an output published, derived from frame `stamp`, at `now_ns`.
    pub fn output(&mut self, stamp: Stamp, now_ns: u64) {
        self.msg.messages_out += 1;
        self.msg.stamp.frame_seq = stamp.frame_seq;
        self.msg.last_latency_ms = (stamp.age_s(now_ns) * 1e3) as f32;
    }

    /// Counts an input dropped as invalid, logging why.
    pub fn dropped(&mut self, why: &dyn Display) {
        self.msg.dropped += 1;
        tracing::warn!(dropped_total = self.msg.dropped, "dropped input: {why}");
    }

    /// Counts an input dropped whose reason another report already logged
    /// (one camera's share of its stage's drops).
    pub fn count_dropped(&mut self) {
        self.msg.dropped += 1;
    }

    /// The report as it goes out at `now_ns`: a stage that sends a report
    /// of its own (one per camera) stamps it the way [`Health`] does.
    pub fn stamped(&self, now_ns: u64) -> StageHealth {
        let mut msg = self.msg;
        msg.stamp.capture_time_ns = now_ns;
        msg
    }

    /// Records the inputs latest-value delivery skipped (a total, not a delta).
    pub fn set_skipped(&mut self, total: u64) {
        self.msg.skipped = total;
    }

    pub fn report(&self) -> &StageHealth {
        &self.msg
    }
}

/// A stage's [`HealthReport`], published on `health/<instance>` at a fixed
/// rate and at once on a change of state; its tick pings systemd's watchdog.
pub struct Health {
    publisher: Publisher<StageHealth>,
    report: HealthReport,
    period_ns: u64,
    last_sent_ns: Option<u64>,
    sent_state: Option<HealthState>,
    watchdog: watchdog::Watchdog,
}

impl std::ops::Deref for Health {
    type Target = HealthReport;
    fn deref(&self) -> &HealthReport {
        &self.report
    }
}

impl std::ops::DerefMut for Health {
    fn deref_mut(&mut self) -> &mut HealthReport {
        &mut self.report
    }
}

impl Health {
    pub fn new(bus: &Bus, stage: &str, rate_hz: f64) -> Result<Self, TransportError> {
        let publisher = bus.publisher(&topics::health(stage))?;
        Ok(Self {
            publisher,
            report: HealthReport::new(stage),
            period_ns: (1e9 / rate_hz.max(0.01)) as u64,
            last_sent_ns: None,
            sent_state: None,
            watchdog: watchdog::Watchdog::from_env(),
        })
    }

    /// Publishes if the period has passed since the last report (or the state
    /// changed), and pings systemd's watchdog: call it from the loop thread on
    /// every tick, so only a loop that keeps turning keeps the stage alive.
    pub fn tick(&mut self, now_ns: u64) {
        self.watchdog.pet();
        let due = self.sent_state != Some(self.report.state())
            || match self.last_sent_ns {
                None => true,
                Some(t) => now_ns.saturating_sub(t) >= self.period_ns,
            };
        if due {
            self.send(now_ns);
        }
    }

    /// Publishes the report now, whatever the period: an answer someone
    /// waits for (the recorder's report of the frame it has taken in, which a
    /// lock-step simulator waits for before its next frame).
    pub fn publish_now(&mut self, now_ns: u64) {
        self.watchdog.pet();
        self.send(now_ns);
    }

    fn send(&mut self, now_ns: u64) {
        self.report.msg = self.report.stamped(now_ns);
        if let Err(e) = self.publisher.publish(&self.report.msg) {
            tracing::warn!("health publish failed: {e}");
        }
        self.last_sent_ns = Some(now_ns);
        self.sent_state = Some(self.report.state());
    }

    /// Publishes a final `stopping` report (on SIGTERM).
    pub fn stopping(&mut self, now_ns: u64) {
        watchdog::notify_stopping();
        self.set(HealthState::STOPPING, "shutting down");
        self.send(now_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, Default)]
    #[serde(deny_unknown_fields, default)]
    struct Cfg {
        rate_hz: f64,
        name: String,
    }

    impl Validate for Cfg {
        fn ranges(&self, r: &mut Ranges) {
            r.key(
                "rate_hz",
                self.rate_hz,
                Range::above_to(0.0, 1000.0).unit("Hz"),
            );
        }
        fn check_rules(&self) -> Result<(), ConfigError> {
            ConfigError::check(!self.name.contains(' '), "name", &self.name, "no spaces")
        }
    }

    /// Minor page faults of the calling thread so far.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn thread_page_faults() -> i64 {
        let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
        // SAFETY: getrusage fills the struct it is given.
        let rc = unsafe { libc::getrusage(libc::RUSAGE_THREAD, usage.as_mut_ptr()) };
        assert_eq!(rc, 0);
        // SAFETY: filled above (and zeroed before).
        unsafe { usage.assume_init() }.ru_minflt
    }

    /// A step's shape: three layers of a megabyte each, made, filled and
    /// freed, again and again. Once the heap has grown to them, later steps
    /// take no page faults (with glibc's defaults each step mapped and
    /// zeroed them again, a page fault per 4 KiB).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[test]
    fn a_steps_freed_buffers_serve_the_next_step_without_page_faults() {
        keep_freed_memory();
        let step = |fill: u8| {
            let layers: Vec<Vec<u8>> = (0..3).map(|_| vec![fill; 1 << 20]).collect();
            std::hint::black_box(&layers);
        };
        step(1);
        step(2);
        let before = thread_page_faults();
        for k in 0..10 {
            step(k);
        }
        let faults = thread_page_faults() - before;
        // 10 steps of 768 pages each would be 7,680 faults.
        assert!(faults < 100, "{faults} page faults in 10 steps");
    }

    #[test]
    fn config_errors_name_key_value_and_expectation() {
        let e = parse_config::<Cfg>("rate_hz = -2.0", "a.toml").unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `rate_hz` = -2: expected 0 < x <= 1000 Hz"
        );
        let e = parse_config::<Cfg>("rate_hz = nan", "a.toml").unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `rate_hz` = NaN: expected 0 < x <= 1000 Hz"
        );
        let e = parse_config::<Cfg>("rate_hz = 1.0\nname = \"a b\"", "a.toml").unwrap_err();
        assert_eq!(e.to_string(), "config key `name` = a b: expected no spaces");
        let e = parse_config::<Cfg>("rate_hz = \"fast\"", "a.toml").unwrap_err();
        let s = e.to_string();
        assert!(s.starts_with("config a.toml:"), "{s}");
        assert!(s.contains("rate_hz") && s.contains("expected"), "{s}");
        let e = parse_config::<Cfg>("rate_hz = 1.0\nrat_hz = 2.0", "a.toml").unwrap_err();
        assert!(e.to_string().contains("unknown field `rat_hz`"), "{e}");
        let ok = parse_config::<Cfg>("rate_hz = 5.0\nname = \"x\"", "a.toml").unwrap();
        assert_eq!((ok.rate_hz, ok.name.as_str()), (5.0, "x"));
    }

    #[test]
    fn nan_and_infinities_are_refused_anywhere_naming_the_key() {
        #[derive(Debug, Deserialize, Default)]
        #[serde(default)]
        struct Nested {
            rate_hz: f64,
            inner: Inner,
            list: Vec<Inner>,
        }
        #[derive(Debug, Deserialize, Default)]
        #[serde(default)]
        struct Inner {
            gain: f64,
            cost_s_per_m: f64,
        }
        impl Validate for Nested {}
        for (text, key, value) in [
            ("rate_hz = nan", "rate_hz", "NaN"),
            ("rate_hz = inf", "rate_hz", "inf"),
            ("[inner]\ngain = -inf", "inner.gain", "-inf"),
            (
                "[[list]]\ngain = 1.0\n[[list]]\ngain = nan",
                "list[1].gain",
                "NaN",
            ),
            ("[inner]\ncost_s_per_m = -inf", "inner.cost_s_per_m", "-inf"),
            ("[inner]\ncost_s_per_m = nan", "inner.cost_s_per_m", "NaN"),
        ] {
            let e = parse_config::<Nested>(text, "n.toml")
                .unwrap_err()
                .to_string();
            assert_eq!(
                e,
                format!("config key `{key}` = {value}: expected {NON_FINITE}"),
                "{text}"
            );
        }
        // A lethal cost is the one meaningful infinity.
        assert!(parse_config::<Nested>("[inner]\ncost_s_per_m = inf", "n.toml").is_ok());
        assert!(parse_config::<Nested>("rate_hz = 1e300\n[inner]\ngain = -2.5", "n.toml").is_ok());
    }

    #[test]
    fn defaults_are_validated_and_missing_files_named() {
        assert!(
            load_config::<Cfg>(None).is_err(),
            "default rate 0 must be refused"
        );
        let e = load_config::<Cfg>(Some(Path::new("/nonexistent/x.toml"))).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("cannot read config /nonexistent/x.toml"),
            "{e}"
        );
    }

    #[test]
    fn anchor_is_both_or_neither_and_in_range() {
        assert!(check_anchor(None, None).is_ok());
        assert!(check_anchor(Some(40.0), Some(-80.0)).is_ok());
        let e = check_anchor(Some(40.0), None).unwrap_err();
        assert!(e.to_string().contains("both or neither"), "{e}");
        let e = check_anchor(Some(95.0), Some(0.0)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `anchor_latitude_deg` = 95: expected [-90, 90] degrees"
        );
    }

    #[test]
    fn args_parse() {
        let a = StageArgs::parse_from("x", ["--config".to_string(), "/etc/f/x.toml".to_string()])
            .unwrap();
        assert_eq!(a.config_dir(), PathBuf::from("/etc/f"));
        assert!(StageArgs::parse_from("x", ["--bogus".to_string()]).is_err());
        assert!(
            StageArgs::parse_from("x", ["--log-format".to_string(), "xml".to_string()]).is_err()
        );
    }
}
