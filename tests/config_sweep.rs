//! Every numeric config key is range-checked where it is declared (issue 17,
//! item 3). For each stage's default config (serialised to TOML), each
//! shipped deploy config and each shipped model config, every numeric leaf is
//! set in turn to NaN, +inf, -inf and the values just outside the range the
//! config declares for it (`Validate::ranges`), and the result is parsed as a
//! stage parses its file at start. Each must be refused naming the key (and,
//! for a range error, the value and the range), never panic. A numeric leaf
//! with no declared range fails the test, so a new key is covered as soon as
//! it exists, without editing this file.

use farsight_stage::{parse_config, ConfigError, Range, Ranges, Validate};
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

/// One config's sweep.
#[derive(Debug, Default)]
struct Report {
    keys: usize,
    tried: usize,
    failures: Vec<String>,
}

/// A numeric leaf of a TOML document: `cameras[0].model.xyz_m[2]`.
struct Leaf {
    key: String,
    integer: bool,
}

fn numeric_leaves(value: &toml::Value, key: &str, out: &mut Vec<Leaf>) {
    let join = |k: &str| {
        if key.is_empty() {
            k.to_string()
        } else {
            format!("{key}.{k}")
        }
    };
    match value {
        toml::Value::Integer(_) => out.push(Leaf {
            key: key.to_string(),
            integer: true,
        }),
        toml::Value::Float(_) => out.push(Leaf {
            key: key.to_string(),
            integer: false,
        }),
        toml::Value::Table(t) => t.iter().for_each(|(k, v)| numeric_leaves(v, &join(k), out)),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, v)| numeric_leaves(v, &format!("{key}[{i}]"), out)),
        _ => {}
    }
}

/// `key` split into table keys and array indices: `a[0].b` -> a, 0, b.
fn path_of(key: &str) -> Vec<Result<String, usize>> {
    let mut out = Vec::new();
    for part in key.split('.') {
        let mut it = part.split('[');
        out.push(Ok(it.next().unwrap().to_string()));
        for idx in it {
            out.push(Err(idx.trim_end_matches(']').parse().unwrap()));
        }
    }
    out
}

fn set(doc: &mut toml::Value, key: &str, to: toml::Value) {
    let mut at = doc;
    for step in path_of(key) {
        at = match step {
            Ok(k) => at.get_mut(&k).unwrap(),
            Err(i) => at.get_mut(i).unwrap(),
        };
    }
    *at = to;
}

fn sweep<T: DeserializeOwned + Validate>(origin: &str, base: &str) -> Report {
    let config: T = parse_config(base, origin).unwrap_or_else(|e| panic!("{origin}: {e}"));
    let declared: HashMap<String, Range> = Ranges::of(&config)
        .declared()
        .iter()
        .map(|d| (d.key.clone(), d.range))
        .collect();
    let doc: toml::Value = toml::from_str(base).unwrap();
    let mut leaves = Vec::new();
    numeric_leaves(&doc, "", &mut leaves);
    let mut report = Report::default();
    for leaf in leaves {
        report.keys += 1;
        let Some(range) = declared.get(&leaf.key) else {
            report
                .failures
                .push(format!("{origin}: `{}` has no declared range", leaf.key));
            continue;
        };
        let mut values = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
        values.extend(range.just_outside(leaf.integer));
        for v in values {
            report.tried += 1;
            let as_toml = if leaf.integer && v.is_finite() {
                toml::Value::Integer(v as i64)
            } else {
                toml::Value::Float(v)
            };
            let mut mutated = doc.clone();
            set(&mut mutated, &leaf.key, as_toml);
            let text = toml::to_string(&mutated).unwrap();
            let what = format!("{origin}: `{} = {v}`", leaf.key);
            match catch_unwind(AssertUnwindSafe(|| parse_config::<T>(&text, origin))) {
                Err(_) => report.failures.push(format!("{what} panicked")),
                Ok(Ok(_)) if range.contains(v) => {} // inf in a lethal cost
                Ok(Ok(_)) => report.failures.push(format!("{what} was accepted")),
                Ok(Err(e)) => {
                    if let Some(why) = misnamed(&e, &leaf, v, range) {
                        report.failures.push(format!("{what}: {why}: {e}"));
                    }
                }
            }
        }
    }
    report
}

/// Why a refusal does not name what it refused, if it does not.
fn misnamed(e: &ConfigError, leaf: &Leaf, v: f64, range: &Range) -> Option<&'static str> {
    match e {
        ConfigError::Invalid {
            key,
            value,
            expected,
        } => {
            if key != &leaf.key {
                return Some("names another key");
            }
            let shown: f64 = value.parse().ok()?;
            let same = shown == v || (shown.is_nan() && v.is_nan()) || (shown - v).abs() < 1e-6;
            if !same {
                return Some("names another value");
            }
            (expected != &range.to_string()).then_some("does not name the declared range")
        }
        // The TOML type is wrong for the key (NaN for an integer, -1 for an
        // unsigned): the parser's error quotes the line, key and value.
        ConfigError::Parse { detail, .. } => {
            let leaf_name = leaf.key.rsplit('.').next().unwrap();
            let leaf_name = leaf_name.split('[').next().unwrap();
            (!detail.contains(leaf_name)).then_some("does not name the key")
        }
        ConfigError::Io { .. } => Some("is an I/O error"),
    }
}

type Sweep = fn(&str, &str) -> Report;

/// A stage's name, the sweep of its config type and its defaults as TOML.
fn stage<T: DeserializeOwned + Serialize + Default + Validate>(
    name: &'static str,
) -> (&'static str, Sweep, String) {
    (name, sweep::<T>, toml::to_string(&T::default()).unwrap())
}

fn shipped(path: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn every_numeric_key_of_every_config_is_refused_outside_its_range() {
    use farsight_bin_projection::stage::BinProjectionConfig;
    use farsight_bridge::BridgeConfig;
    use farsight_camera_ingest::IngestConfig;
    use farsight_command_mux::MuxConfig;
    use farsight_costmap_fusion::stage::FusionStageConfig;
    use farsight_inference::class_table::ClassTableConfig;
    use farsight_inference::model_config::ModelConfig;
    use farsight_inference::stage::InferenceConfig;
    use farsight_subgoal_selection::stage::SubgoalStageConfig;
    use farsight_velocity_servoing::stage::ServoStageConfig;

    // Each stage's defaults and its shipped config in deploy/config.
    let stages = [
        stage::<IngestConfig>("camera-ingest"),
        stage::<InferenceConfig>("inference"),
        stage::<BinProjectionConfig>("bin-projection"),
        stage::<FusionStageConfig>("costmap-fusion"),
        stage::<SubgoalStageConfig>("subgoal-selection"),
        stage::<ServoStageConfig>("velocity-servoing"),
        stage::<MuxConfig>("command-mux"),
        stage::<BridgeConfig>("bridge"),
    ];
    let mut runs = Vec::new();
    for (name, run, defaults) in &stages {
        let origin = format!("{name} defaults");
        runs.push((origin.clone(), run(&origin, defaults)));
        let path = format!("deploy/config/{name}.toml");
        runs.push((path.clone(), run(&path, &shipped(&path))));
    }
    for (path, run) in [
        (
            "deploy/models/twinlitenet.toml",
            sweep::<ModelConfig> as Sweep,
        ),
        ("deploy/models/deeplabv3-voc.toml", sweep::<ModelConfig>),
        ("deploy/models/sim-fitam/model.toml", sweep::<ModelConfig>),
        ("deploy/models/sim-lrn/model.toml", sweep::<ModelConfig>),
        ("deploy/models/sim-hip/model.toml", sweep::<ModelConfig>),
        (
            "deploy/models/twinlitenet-classes.toml",
            sweep::<ClassTableConfig>,
        ),
        ("deploy/models/voc-classes.toml", sweep::<ClassTableConfig>),
    ] {
        runs.push((path.to_string(), run(path, &shipped(path))));
    }

    let mut failures = Vec::new();
    let (mut keys, mut tried) = (0, 0);
    println!(
        "{:<42} {:>5} {:>7} {:>9}",
        "config", "keys", "values", "failures"
    );
    for (name, r) in &runs {
        println!(
            "{name:<42} {:>5} {:>7} {:>9}",
            r.keys,
            r.tried,
            r.failures.len()
        );
        keys += r.keys;
        tried += r.tried;
        failures.extend(r.failures.iter().cloned());
    }
    println!("{:<42} {keys:>5} {tried:>7} {:>9}", "total", failures.len());
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
    // Every stage's defaults have numeric keys: a sweep of nothing proves nothing.
    assert!(
        runs.iter()
            .filter(|(name, _)| name.ends_with("defaults"))
            .all(|(_, r)| r.keys > 0),
        "a stage's defaults with no numeric key swept"
    );
}
