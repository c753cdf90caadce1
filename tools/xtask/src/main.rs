//! Project automation, as `cargo xtask <command>`:
//!
//! - `setup`: fetch ONNX Runtime from the `onnxruntime` PyPI wheel into the
//!   cache (`$FARSIGHT_CACHE`, default `~/.cache/farsight`) and print its path;
//! - `test`: every check CI runs: fmt, clippy, build, all tests, then one
//!   summary line;
//! - `bench NAME`: `farsight bench NAME` (transport, navigation, planning, nav, inference, recorder);
//! - `demo`: build and run the closed loop in the simulator (`--orfd`: the graph
//!   on the real frames in `../shared/data/orfd`);
//! - `fixtures [sim|orfd]`: regenerate the replay fixtures in `tests/fixtures/`
//!   (`sim-povnav/` with its goldens, after an intended change of the
//!   outputs; `orfd/`, the real frames as recorded over zenoh).
//!
//! Dependency-free on purpose, so it starts in seconds on a fresh clone.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};

/// The ONNX Runtime release `ort` 2.0.0-rc.15 targets.
const ORT_VERSION: &str = "1.31.1";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("setup") => setup().map(|p| println!("ONNX Runtime: {}", p.display())),
        Some("test") => test(),
        Some("bench") => bench(&args[1..]),
        Some("demo") => demo(&args[1..]),
        Some("fixtures") => fixtures(&args[1..]),
        _ => {
            eprintln!(
                "usage: cargo xtask <command>\n\n  setup             fetch ONNX Runtime {ORT_VERSION} (PyPI wheel) into the cache\n  test              fmt, clippy, build and every test\n  bench NAME        transport | navigation | planning | nav | inference | recorder (farsight bench NAME --help)\n  demo [ARGS]       the closed loop in the simulator (bug-trap); --orfd: real frames\n  fixtures [sim|orfd]  regenerate tests/fixtures (the replay fixtures and their goldens)"
            );
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}

type Result<T> = std::result::Result<T, String>;

fn root() -> PathBuf {
    // tools/xtask -> repository root
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .nth(2)
        .expect("xtask lives in tools/xtask")
        .to_path_buf()
}

fn cache_dir() -> PathBuf {
    if let Ok(d) = std::env::var("FARSIGHT_CACHE") {
        return PathBuf::from(d);
    }
    let home = std::env::var("HOME").unwrap_or_else(|_| "/tmp".into());
    PathBuf::from(home).join(".cache/farsight")
}

fn run(cmd: &mut Command) -> Result<()> {
    let shown = std::iter::once(cmd.get_program())
        .chain(cmd.get_args())
        .map(|a| a.to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join(" ");
    eprintln!("xtask: running {shown}");
    let status = cmd.status().map_err(|e| format!("{shown}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{shown} failed ({status})"))
    }
}

fn cargo() -> Command {
    let mut c = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    c.current_dir(root());
    // `cargo run` hands xtask its own package's environment; passed on, it changes
    // build-script fingerprints and a plain `cargo build` would rebuild everything.
    for (k, _) in std::env::vars_os() {
        let k = k.to_string_lossy().to_string();
        if k == "LD_LIBRARY_PATH"
            || (k.starts_with("CARGO_") && k != "CARGO_HOME" && k != "CARGO_TARGET_DIR")
        {
            c.env_remove(k);
        }
    }
    c
}

/// Makes sure the ONNX Runtime shared library is in the cache; returns its path.
/// Downloads the `onnxruntime` wheel with `pip download` (nothing is installed
/// into Python) and unpacks only the library.
fn setup() -> Result<PathBuf> {
    let dir = cache_dir().join(format!("onnxruntime-{ORT_VERSION}"));
    let lib = dir.join(format!("libonnxruntime.so.{ORT_VERSION}"));
    if lib.exists() {
        return Ok(lib);
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    let tmp = dir.join("download");
    let _ = std::fs::remove_dir_all(&tmp);
    eprintln!("xtask: fetching onnxruntime=={ORT_VERSION} from PyPI (about 17 MB, once)");
    run(Command::new("python3")
        .args([
            "-m",
            "pip",
            "download",
            "--quiet",
            "--no-deps",
            "--disable-pip-version-check",
        ])
        .arg(format!("onnxruntime=={ORT_VERSION}"))
        .arg("-d")
        .arg(&tmp))?;
    let wheel = std::fs::read_dir(&tmp)
        .map_err(|e| e.to_string())?
        .flatten()
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|x| x == "whl"))
        .ok_or("pip download produced no wheel")?;
    let member = format!("onnxruntime/capi/libonnxruntime.so.{ORT_VERSION}");
    let script = format!(
        "import zipfile,sys\nz=zipfile.ZipFile(sys.argv[1])\nopen(sys.argv[2],'wb').write(z.read('{member}'))\n\
         [open(sys.argv[3]+'/'+n.split('/')[-1],'wb').write(z.read(n)) for n in z.namelist() if n.endswith('.onnx') and '/datasets/' in n]"
    );
    let partial = dir.join("libonnxruntime.partial");
    run(Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(&wheel)
        .arg(&partial)
        .arg(&dir))?;
    // Rename last, so an interrupted download never leaves a half library behind.
    std::fs::rename(&partial, &lib).map_err(|e| e.to_string())?;
    let _ = std::fs::remove_dir_all(&tmp);
    Ok(lib)
}

/// Runs `cargo test` with output passed through, and adds up its result lines.
fn cargo_test(ort: &Path) -> Result<(u64, u64, u64)> {
    let mut child = cargo()
        .args(["test", "--release", "--workspace", "--no-fail-fast"])
        .env("ORT_DYLIB_PATH", ort)
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| e.to_string())?;
    let (mut passed, mut failed, mut ignored) = (0, 0, 0);
    for line in BufReader::new(child.stdout.take().expect("stdout"))
        .lines()
        .map_while(|l| l.ok())
    {
        println!("{line}");
        if let Some(rest) = line.strip_prefix("test result: ") {
            let num = |word: &str| {
                rest.split(';')
                    .find_map(|part| part.trim().strip_suffix(word).map(str::trim))
                    .and_then(|n| n.rsplit(' ').next())
                    .and_then(|n| n.parse::<u64>().ok())
                    .unwrap_or(0)
            };
            passed += num("passed");
            failed += num("failed");
            ignored += num("ignored");
        }
    }
    let status = child.wait().map_err(|e| e.to_string())?;
    if !status.success() && failed == 0 {
        failed += 1; // a test binary that failed to build or crashed
    }
    Ok((passed, failed, ignored))
}

fn test() -> Result<()> {
    let ort = setup()?;
    run(cargo().args(["fmt", "--all", "--check"]))?;
    run(cargo().args([
        "clippy",
        "--release",
        "--workspace",
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ]))?;
    // The end-to-end tests start the real binaries, so build them all first.
    run(cargo().args(["build", "--release", "--workspace"]))?;
    let (passed, failed, ignored) = cargo_test(&ort)?;
    println!("summary: {passed} passed, {failed} failed, {ignored} skipped");
    if failed > 0 {
        return Err(format!("{failed} tests failed"));
    }
    Ok(())
}

fn bench(args: &[String]) -> Result<()> {
    // Each name is a `farsight bench` subcommand; the rest of the line goes with it.
    const KNOWN: [&str; 6] = [
        "transport",
        "navigation",
        "planning",
        "nav",
        "inference",
        "recorder",
    ];
    match args.first().map(String::as_str) {
        Some(name) if KNOWN.contains(&name) => {
            let mut cmd = Command::new(root().join("target/release/farsight"));
            if name == "inference" {
                cmd.env("ORT_DYLIB_PATH", setup()?);
            }
            run(cargo().args(["build", "--release", "--workspace"]))?;
            run(cmd.current_dir(root()).arg("bench").args(args))
        }
        other => Err(format!(
            "unknown benchmark {other:?}: try one of {}",
            KNOWN.join(", ")
        )),
    }
}

/// The topics the golden tests replay, and the outputs they compare.
const FIXTURE_INPUTS: &str = "camera/front/image,camera/front/info,state/pose,nav/goal";
const FIXTURE_OUTPUTS: &str =
    "perception/front/navigability,nav/subgoal,nav/path/visual,cmd/velocity";

/// The replay fixture: 8 s of the POVNav demo on bush-wall, recorded with
/// every topic (`recording.mcap`: its simulator topics are the inputs the
/// golden tests replay), the stage configs the demo wrote, and the goldens
/// (`golden.mcap`): every output of every frame when those inputs are
/// replayed lock-step through the stages. The goldens come from a replay
/// rather than from the demo's own recording because the recorder, a
/// latest-value subscriber, may skip a message when the lock-step demo runs
/// faster than it writes; a lock-step replay waits for every answer.
fn fixtures(which: &[String]) -> Result<()> {
    let want = |name: &str| which.is_empty() || which.iter().any(|w| w == name);
    if want("sim") {
        sim_fixture()?;
    }
    if want("orfd") {
        run(cargo().args(["build", "--release", "--workspace"]))?;
        orfd_fixture()?;
    }
    Ok(())
}

fn sim_fixture() -> Result<()> {
    let out = root().join("target/fixture-run");
    let _ = std::fs::remove_dir_all(&out);
    demo(&[
        "--method".into(),
        "povnav".into(),
        "--scenario".into(),
        "bush-wall".into(),
        "--max-time-s".into(),
        "8".into(),
        "--out".into(),
        out.display().to_string(),
    ])?;
    let dest = root().join("tests/fixtures/sim-povnav");
    std::fs::create_dir_all(&dest).map_err(|e| format!("{}: {e}", dest.display()))?;
    for f in [
        "recording.mcap",
        "inference.toml",
        "subgoal-selection.toml",
        "velocity-servoing.toml",
    ] {
        std::fs::copy(out.join(f), dest.join(f)).map_err(|e| format!("copying {f}: {e}"))?;
    }
    let bin = root().join("target/release");
    let prefix = format!("fixture{}_", std::process::id());
    let mut stages = Vec::new();
    for stage in ["inference", "subgoal-selection", "velocity-servoing"] {
        let mut child = Command::new(bin.join(format!("farsight-{stage}")))
            .arg("--config")
            .arg(dest.join(format!("{stage}.toml")))
            .env("FARSIGHT_IPC_PREFIX", &prefix)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("starting {stage}: {e}"))?;
        let mut line = String::new();
        let _ = BufReader::new(child.stdout.take().expect("piped")).read_line(&mut line);
        stages.push(child);
    }
    let replayed = run(Command::new(bin.join("farsight"))
        .env("FARSIGHT_IPC_PREFIX", &prefix)
        .arg("replay")
        .arg(dest.join("recording.mcap"))
        .args(["--topics", FIXTURE_INPUTS, "--lockstep"])
        .args([
            "--driving",
            "camera/front/image",
            "--answer",
            FIXTURE_OUTPUTS,
        ])
        .arg("--record-answers")
        .arg(dest.join("golden.mcap")));
    for mut s in stages {
        let _ = s.kill();
        let _ = s.wait();
    }
    replayed?;
    println!("fixture and goldens written to {}", dest.display());
    Ok(())
}

/// `tests/fixtures/orfd/recording.mcap`: the six real ORFD frames as a
/// laptop records them from a robot. camera-ingest publishes them, the
/// bridge exports them over zenoh at half size as JPEG (about 60 KB each),
/// and `farsight record --connect` writes them.
fn orfd_fixture() -> Result<()> {
    let bin = root().join("target/release");
    let dest = root().join("tests/fixtures/orfd");
    std::fs::create_dir_all(&dest).map_err(|e| format!("{}: {e}", dest.display()))?;
    let work = root().join("target/fixture-orfd");
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).map_err(|e| e.to_string())?;
    let port = 20000 + std::process::id() % 20000;
    let write = |name: &str, text: String| -> Result<PathBuf> {
        let p = work.join(name);
        std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))?;
        Ok(p)
    };
    let bridge = write(
        "bridge.toml",
        format!(
            "robot = \"fixture\"\n[zenoh]\nmode = \"peer\"\nlisten = [\"tcp/127.0.0.1:{port}\"]\n\
             [[export]]\ntopic = \"camera/front/image\"\ndownsample = 2\ncompression = \"jpeg\"\njpeg_quality = 85\n\
             [[export]]\ntopic = \"camera/front/info\"\n"
        ),
    )?;
    let ingest = write(
        "camera-ingest.toml",
        format!(
            "[[cameras]]\nfolder = {:?}\nrate_hz = 4.0\nloops = 1\n[cameras.model]\nname = \"front\"\n\
             width = 1280\nheight = 720\nfx = 1487.75\nfy = 1471.06\ncx = 625.01\ncy = 376.48\n",
            root().join("../shared/data/orfd/image_data").display().to_string()
        ),
    )?;
    let prefix = format!("fixtureorfd{}_", std::process::id());
    let spawn = |program: PathBuf, args: Vec<String>| -> Result<std::process::Child> {
        let mut child = Command::new(&program)
            .args(&args)
            .env("FARSIGHT_IPC_PREFIX", &prefix)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("starting {}: {e}", program.display()))?;
        // Each prints one line when it is ready.
        let mut line = String::new();
        let _ = BufReader::new(child.stdout.take().expect("piped")).read_line(&mut line);
        Ok(child)
    };
    let stop = |mut c: std::process::Child| {
        let _ = Command::new("kill")
            .args(["-TERM", &c.id().to_string()])
            .status();
        let _ = c.wait();
    };
    let bridge = spawn(
        bin.join("farsight-bridge"),
        vec!["--config".into(), bridge.display().to_string()],
    )?;
    let recorder = spawn(
        bin.join("farsight"),
        vec![
            "record".into(),
            "--connect".into(),
            format!("tcp/127.0.0.1:{port}"),
            "--robot".into(),
            "fixture".into(),
            "--topics".into(),
            "camera/front/**".into(),
            "--out".into(),
            dest.join("recording.mcap").display().to_string(),
        ],
    )?;
    std::thread::sleep(std::time::Duration::from_secs(1));
    let mut ingest = spawn(
        bin.join("farsight-camera-ingest"),
        vec!["--config".into(), ingest.display().to_string()],
    )?;
    let _ = ingest.wait();
    std::thread::sleep(std::time::Duration::from_secs(1));
    stop(recorder);
    stop(bridge);
    run(Command::new(bin.join("farsight"))
        .args(["record", "--info"])
        .arg(dest.join("recording.mcap")))
}

fn demo(args: &[String]) -> Result<()> {
    let ort = setup()?;
    run(cargo().args(["build", "--release", "--workspace"]))?;
    run(Command::new(root().join("target/release/farsight"))
        .current_dir(root())
        .env("ORT_DYLIB_PATH", ort)
        .arg("demo")
        .args(args))
}
