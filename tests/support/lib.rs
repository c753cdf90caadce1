//! Helpers for the end-to-end tests: find the built binaries, run them as real
//! processes in an isolated iceoryx2 namespace, watch their output, and kill
//! them (SIGKILL, reaped) when a test ends or wants a crash.

pub mod netns;
pub mod onnx_fixture;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// Path of a workspace binary, built by `cargo build --release --workspace`
/// (which `cargo xtask test` runs first).
pub fn bin(name: &str) -> PathBuf {
    // current_exe = target/<profile>/deps/<test>-<hash>
    let exe = std::env::current_exe().expect("current_exe");
    let dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("test binary lives in target/<profile>/deps");
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} not found: build the workspace binaries first (cargo build --release --workspace, or cargo xtask test)",
        path.display()
    );
    path
}

/// An iceoryx2 namespace of one test: its own resource prefix and root
/// directory, so tests run in parallel without seeing each other. Dropping it
/// removes what the test's processes left in `/dev/shm` and the root directory;
/// declare it before the test's [`Proc`]s so they are killed first.
pub struct Namespace {
    pub prefix: String,
    pub root: PathBuf,
}

impl Namespace {
    pub fn new(test: &str) -> Self {
        let short: String = test
            .chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .take(12)
            .collect();
        let prefix = format!(
            "t{}_{}_{}_",
            std::process::id() % 100_000,
            short,
            nanos() % 1_000_000
        );
        let root = std::env::temp_dir().join(format!("farsight-{prefix}"));
        std::fs::create_dir_all(&root).expect("namespace root");
        Self { prefix, root }
    }

    /// Environment that puts a process into this namespace.
    pub fn env(&self) -> [(&'static str, String); 2] {
        [
            ("FARSIGHT_IPC_PREFIX", self.prefix.clone()),
            ("FARSIGHT_IPC_ROOT", format!("{}/", self.root.display())),
        ]
    }

    /// Opens a bus in this namespace from the test process itself.
    pub fn bus(&self, name: &str) -> farsight_interfaces::transport::ipc::Bus {
        self.bus_with_queues(name, None)
    }

    /// [`Namespace::bus`] with queued topics declared (`topic=depth,...`,
    /// as `FARSIGHT_QUEUES`).
    pub fn bus_with_queues(
        &self,
        name: &str,
        queues: Option<&str>,
    ) -> farsight_interfaces::transport::ipc::Bus {
        farsight_interfaces::transport::ipc::Bus::open_with(
            name,
            &farsight_interfaces::transport::ipc::IpcSettings {
                prefix: Some(self.prefix.clone()),
                root: Some(format!("{}/", self.root.display())),
                queues: queues.map(str::to_string),
            },
        )
        .expect("test bus")
    }

    /// Writes a file into the namespace's directory and returns its path.
    pub fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.root.join(name);
        std::fs::write(&p, text).expect("write test file");
        p
    }

    /// Starts a stage that must refuse to start; returns what it wrote to stderr.
    pub fn start_must_fail(&self, binary: &str, config: &std::path::Path) -> String {
        let mut p = Proc::start(
            binary,
            &["--config", config.to_str().expect("utf-8 path")],
            self,
        );
        assert_eq!(
            p.wait_exit(Duration::from_secs(10)),
            Some(1),
            "{binary} should have failed at start-up"
        );
        p.stderr_to_end()
    }

    /// The shipped robot router config (`deploy/zenoh/robot.json5`: laptops
    /// read, only the operator commands) listening on `listen` (e.g.
    /// `tcp/127.0.0.1:7447`) with the shipped users file, both written
    /// here; its path, for a bridge config's `zenoh.config_file`.
    pub fn shipped_router(&self, listen: &str) -> PathBuf {
        let users = self.write(
            "users.txt",
            &std::fs::read_to_string(repo_root().join("deploy/zenoh/users.txt")).unwrap(),
        );
        let router = std::fs::read_to_string(repo_root().join("deploy/zenoh/robot.json5"))
            .unwrap()
            .replace("tcp/0.0.0.0:7447", listen)
            .replace("/etc/farsight/zenoh/users.txt", users.to_str().unwrap());
        self.write("robot.json5", &router)
    }

    /// `farsight-bridge` from `config`, once it printed `bridge ready`.
    pub fn start_bridge(&self, config: &std::path::Path) -> Proc {
        self.start_bridge_in(None, config)
    }

    /// [`Namespace::start_bridge`] in network namespace `netns`.
    pub fn start_bridge_in(&self, netns: Option<&str>, config: &std::path::Path) -> Proc {
        let bridge = Proc::start_in(
            netns,
            "farsight-bridge",
            &["--config", config.to_str().expect("utf-8 path")],
            self,
            &[],
        );
        bridge
            .wait_line(Duration::from_secs(20), |l| l == "bridge ready")
            .unwrap_or_else(|| panic!("bridge did not start:\n{}", bridge.stderr_so_far()));
        bridge
    }

    /// Graph file `graph` started through `farsight run` (with extra
    /// environment; node configs and logs in `<root>/run`), once every node
    /// in `nodes` said it is ready. A test of a chain of stages starts it
    /// so, as a robot does: a test of one stage, with the test as its
    /// peers, starts that stage alone ([`Namespace::start_stage`]).
    pub fn run_graph_file(
        &self,
        graph: &std::path::Path,
        nodes: &[&str],
        env: &[(&str, &str)],
    ) -> Proc {
        self.run_graph_file_in(None, graph, nodes, env)
    }

    /// [`Namespace::run_graph_file`] in network namespace `netns`.
    pub fn run_graph_file_in(
        &self,
        netns: Option<&str>,
        graph: &std::path::Path,
        nodes: &[&str],
        env: &[(&str, &str)],
    ) -> Proc {
        let out = self.root.join("run");
        let run = Proc::start_in(
            netns,
            "farsight",
            &[
                "run",
                graph.to_str().expect("utf-8 path"),
                "--out",
                out.to_str().expect("utf-8 path"),
            ],
            self,
            env,
        );
        let ready: Vec<String> = nodes.iter().map(|s| format!("{s}: ready")).collect();
        let ready: Vec<&str> = ready.iter().map(String::as_str).collect();
        let missing = run.wait_all_lines(Duration::from_secs(60), &ready);
        assert!(
            missing.is_empty(),
            "farsight run never printed {missing:?}:\n{}\n{}",
            run.stderr_so_far(),
            nodes
                .iter()
                .map(|n| format!("--- {n}.log\n{}", self.node_log(n)))
                .collect::<String>()
        );
        run
    }

    /// A graph of `nodes` (each a stage kind, as its instance name, and its
    /// config file) in which the test writes `test_writes` and reads
    /// `test_reads`, written into the namespace (`graph.toml`, through the
    /// TOML serializer) and started through `farsight run`
    /// ([`Namespace::run_graph_file`]).
    pub fn run_graph(
        &self,
        nodes: &[(&str, &std::path::Path)],
        test_writes: &[&str],
        test_reads: &[&str],
    ) -> Proc {
        self.run_graph_in(None, nodes, test_writes, test_reads)
    }

    /// [`Namespace::run_graph`] in network namespace `netns`.
    pub fn run_graph_in(
        &self,
        netns: Option<&str>,
        nodes: &[(&str, &std::path::Path)],
        test_writes: &[&str],
        test_reads: &[&str],
    ) -> Proc {
        use toml::{Table, Value};
        let node = |(stage, config): &(&str, &std::path::Path)| {
            let mut t = Table::new();
            t.insert("name".into(), Value::from(*stage));
            t.insert("stage".into(), Value::from(*stage));
            t.insert(
                "config".into(),
                Value::from(config.to_str().expect("utf-8 path")),
            );
            Value::Table(t)
        };
        let external = |key: &str, topic: &&str| {
            let mut t = Table::new();
            t.insert("topic".into(), Value::from(*topic));
            t.insert(key.into(), Value::from("the test"));
            Value::Table(t)
        };
        let mut graph = Table::new();
        graph.insert(
            "node".into(),
            Value::Array(nodes.iter().map(node).collect()),
        );
        graph.insert(
            "external".into(),
            Value::Array(
                test_writes
                    .iter()
                    .map(|t| external("from", t))
                    .chain(test_reads.iter().map(|t| external("to", t)))
                    .collect(),
            ),
        );
        let file = self.write(
            "graph.toml",
            &toml::to_string(&graph).expect("a TOML table"),
        );
        let names: Vec<&str> = nodes.iter().map(|(n, _)| *n).collect();
        self.run_graph_file_in(netns, &file, &names, &[])
    }

    /// What node `node` of a graph started by [`Namespace::run_graph_file`]
    /// has logged so far (for a failing test's message).
    pub fn node_log(&self, node: &str) -> String {
        let path = self.root.join("run").join(format!("{node}.log"));
        std::fs::read_to_string(&path).unwrap_or_else(|e| format!("({}: {e})", path.display()))
    }

    /// `Proc::start` that waits for the stage's `<name> ready` line.
    pub fn start_stage(&self, binary: &str, stage: &str, config: &std::path::Path) -> Proc {
        self.start_stage_in(None, binary, stage, config)
    }

    /// [`Namespace::start_stage`] in network namespace `netns`.
    pub fn start_stage_in(
        &self,
        netns: Option<&str>,
        binary: &str,
        stage: &str,
        config: &std::path::Path,
    ) -> Proc {
        let p = Proc::start_in(
            netns,
            binary,
            &["--config", config.to_str().expect("utf-8 path")],
            self,
            &[],
        );
        let ready = format!("{stage} ready");
        p.wait_line(Duration::from_secs(30), |l| l == ready)
            .unwrap_or_else(|| panic!("{binary} did not get ready:\n{}", p.stderr_so_far()));
        p
    }
}

/// Fraction of navigable (255) pixels of a `w` x `h` mask inside a box given as
/// fractions of the image: `x = (left, right)`, `y = (top, bottom)`.
pub fn navigable_fraction(mask: &[u8], w: usize, h: usize, x: (f64, f64), y: (f64, f64)) -> f64 {
    let (mut n, mut total) = (0usize, 0usize);
    for row in (y.0 * h as f64) as usize..(y.1 * h as f64) as usize {
        for col in (x.0 * w as f64) as usize..(x.1 * w as f64) as usize {
            total += 1;
            n += (mask[row * w + col] == 255) as usize;
        }
    }
    n as f64 / total.max(1) as f64
}

/// Polls a stage's health topic until a report satisfies `pred`; panics
/// after `timeout` with the last report seen. Health is published about once
/// a second, so tests read counts from it instead of racing the stage.
pub fn wait_health(
    health: &farsight_interfaces::transport::ipc::Subscriber<farsight_interfaces::msg::StageHealth>,
    timeout: Duration,
    what: &str,
    pred: impl Fn(&farsight_interfaces::msg::StageHealth) -> bool,
) -> farsight_interfaces::msg::StageHealth {
    let end = Instant::now() + timeout;
    let mut last = None;
    while Instant::now() < end {
        if let Some(h) = health.latest().expect("health topic") {
            if pred(&h) {
                return h;
            }
            last = Some(h);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    panic!("no health report {what} within {timeout:?}; last: {last:?}");
}

/// camera-ingest's config for the six real ORFD frames (one camera,
/// `front`, with the ORFD intrinsics of `tests/fixtures/orfd/front.yaml`),
/// plus `extra` keys of that camera. With `pace_by` in `extra` it is
/// lock-step: each frame waits for the consumer's answer to the one
/// before, so no frame is skipped however slow the machine.
pub fn orfd_ingest_toml(extra: &str) -> String {
    let frames = repo_root().join("../shared/data/orfd/image_data");
    let camera_info = repo_root().join("tests/fixtures/orfd/front.yaml");
    // The model table comes last, so a test that mounts the camera appends
    // its `xyz_m`/`rpy_deg` lines.
    format!(
        "[[cameras]]\nfolder = {}\n{extra}\n[cameras.model]\nname = \"front\"\ncamera_info = {}\n",
        toml_string(&frames.display().to_string()),
        toml_string(&camera_info.display().to_string())
    )
}

/// The files of a folder of `../shared/data/orfd` (`image_data`,
/// `dense_depth`), sorted: every ORFD test reads the frames in one order.
pub fn orfd_files(folder: &str) -> Vec<PathBuf> {
    let dir = repo_root().join("../shared/data/orfd").join(folder);
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .collect();
    files.sort();
    files
}

/// `s` as a TOML string, written by the TOML serializer (Rust's `{:?}`
/// quoting is not TOML for control characters).
pub fn toml_string(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

/// The box of the ORFD frames where the dirt road lies ahead of the vehicle.
pub const ORFD_ROAD_AHEAD: ((f64, f64), (f64, f64)) = ((0.25, 0.45), (0.80, 0.97));
/// The top rows of the ORFD frames: sky.
pub const ORFD_SKY: ((f64, f64), (f64, f64)) = ((0.0, 1.0), (0.0, 0.12));

/// The repository root (tests read ../shared relative to it).
pub fn repo_root() -> PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ is inside the repository")
        .to_path_buf()
}

impl Namespace {
    /// Applies this namespace to the current (test) process.
    pub fn enter(&self) {
        for (k, v) in self.env() {
            std::env::set_var(k, v);
        }
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.root);
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(&self.prefix) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}

fn nanos() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0)
}

/// A free TCP port on loopback.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

/// A running child process whose stdout lines arrive on a channel, stamped
/// with the time they were read. Killed and reaped on drop.
pub struct Proc {
    pub name: String,
    child: Option<Child>,
    lines: Receiver<(Instant, String)>,
    stderr: Receiver<String>,
    /// Every stderr line read so far: [`Proc::stderr_so_far`] keeps what it
    /// read, so a failure message can show the same lines an assert saw.
    stderr_seen: std::cell::RefCell<Vec<String>>,
}

impl Proc {
    /// Starts `bin(name)` with `args` in the iceoryx2 namespace `ns`.
    pub fn start(name: &str, args: &[&str], ns: &Namespace) -> Self {
        Self::start_env(name, args, ns, &[])
    }

    pub fn start_env(name: &str, args: &[&str], ns: &Namespace, env: &[(&str, &str)]) -> Self {
        Self::start_in(None, name, args, ns, env)
    }

    /// [`Proc::start_env`] inside network namespace `netns` (`ip netns exec`,
    /// which execs the binary: the pid is the binary's).
    pub fn start_in(
        netns: Option<&str>,
        name: &str,
        args: &[&str],
        ns: &Namespace,
        env: &[(&str, &str)],
    ) -> Self {
        let mut cmd = match netns {
            Some(n) => {
                let mut c = Command::new("ip");
                c.args(["netns", "exec", n]).arg(bin(name));
                c
            }
            None => Command::new(bin(name)),
        };
        cmd.args(args)
            .envs(ns.env())
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "info".into()),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        Self::spawn(name, cmd)
    }

    /// Starts `cmd` as it is (its stdout and stderr are taken over): for
    /// commands that are not a workspace binary in a namespace, e.g. an
    /// installed binary run as another user.
    pub fn spawn(name: &str, mut cmd: Command) -> Self {
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("starting {name}: {e}"));
        let (tx, lines) = channel();
        let out = child.stdout.take().expect("stdout");
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send((Instant::now(), line)).is_err() {
                    break;
                }
            }
        });
        let (etx, stderr) = channel();
        let err = child.stderr.take().expect("stderr");
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                if etx.send(line).is_err() {
                    break;
                }
            }
        });
        Self {
            name: name.to_string(),
            child: Some(child),
            lines,
            stderr,
            stderr_seen: Default::default(),
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.as_ref().map(|c| c.id()).unwrap_or(0)
    }

    /// The pid of this process's child started as graph node `instance`
    /// (`--instance <instance>` on its command line): how a test finds a
    /// node `farsight run` started, to kill or freeze it.
    pub fn child_instance_pid(&self, instance: &str) -> Option<u32> {
        let parent = self.pid();
        for entry in std::fs::read_dir("/proc").ok()?.flatten() {
            let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
                continue;
            };
            // `pid (comm) state ppid ...`: comm may hold spaces and ')'.
            let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else {
                continue;
            };
            let ppid = stat
                .rsplit_once(')')
                .and_then(|(_, rest)| rest.split_whitespace().nth(1))
                .and_then(|p| p.parse::<u32>().ok());
            if ppid != Some(parent) {
                continue;
            }
            let Ok(cmdline) = std::fs::read(entry.path().join("cmdline")) else {
                continue;
            };
            let args: Vec<&[u8]> = cmdline.split(|&b| b == 0).collect();
            if args
                .windows(2)
                .any(|w| w[0] == b"--instance" && w[1] == instance.as_bytes())
            {
                return Some(pid);
            }
        }
        None
    }

    /// The next stdout line matching `pred`, waiting at most `timeout`.
    pub fn wait_line(
        &self,
        timeout: Duration,
        pred: impl Fn(&str) -> bool,
    ) -> Option<(Instant, String)> {
        let end = Instant::now() + timeout;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok((t, l)) if pred(&l) => return Some((t, l)),
                Ok(_) => continue,
                Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => {
                    return None
                }
            }
        }
    }

    /// Waits for a line containing each of `needles`, in whatever order
    /// they come (the nodes of a graph get ready concurrently); returns the
    /// needles never seen.
    pub fn wait_all_lines<'a>(&self, timeout: Duration, needles: &[&'a str]) -> Vec<&'a str> {
        let end = Instant::now() + timeout;
        let mut missing: Vec<&str> = needles.to_vec();
        while !missing.is_empty() {
            let left = end.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok((_, l)) => missing.retain(|n| !l.contains(n)),
                Err(_) => break,
            }
        }
        missing
    }

    /// Runs `farsight ARGS --user USER` (in network namespace `netns`, if
    /// given) with the password in `FARSIGHT_ZENOH_PASSWORD`, to its end:
    /// the exit code and everything it printed.
    pub fn farsight_as(
        netns: Option<&str>,
        ns: &Namespace,
        user: &str,
        password: &str,
        args: &[&str],
    ) -> (Option<i32>, String) {
        let mut all = args.to_vec();
        all.extend_from_slice(&["--user", user]);
        let mut p = Self::start_in(
            netns,
            "farsight",
            &all,
            ns,
            &[("FARSIGHT_ZENOH_PASSWORD", password)],
        );
        let code = p.wait_exit(Duration::from_secs(30));
        let out: Vec<String> = std::iter::from_fn(|| {
            p.wait_line(Duration::from_millis(100), |_| true)
                .map(|(_, l)| l)
        })
        .collect();
        (code, format!("{}\n{}", out.join("\n"), p.stderr_to_end()))
    }

    /// Everything the process wrote to stderr, once it has exited: waits (up
    /// to 2 s) until its reader has seen the end of the stream.
    pub fn stderr_to_end(&self) -> String {
        self.read_stderr(Some(Duration::from_secs(2)))
    }

    /// Everything written to stderr so far. Once [`Proc::wait_exit`] has seen
    /// the process end, this waits (up to 2 s) for the end of the stream, so
    /// the last lines a process wrote before it exited are never missed.
    pub fn stderr_so_far(&self) -> String {
        let exited = self.child.is_none();
        self.read_stderr(exited.then_some(Duration::from_secs(2)))
    }

    fn read_stderr(&self, to_end: Option<Duration>) -> String {
        let mut seen = self.stderr_seen.borrow_mut();
        match to_end {
            None => seen.extend(self.stderr.try_iter()),
            Some(limit) => {
                let end = Instant::now() + limit;
                loop {
                    let left = end.saturating_duration_since(Instant::now());
                    match self.stderr.recv_timeout(left) {
                        Ok(l) => seen.push(l),
                        Err(_) => break,
                    }
                }
            }
        }
        seen.join("\n")
    }

    /// Waits for the process to exit; returns its exit code.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<i32> {
        let end = Instant::now() + timeout;
        let child = self.child.as_mut()?;
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                self.child = None;
                return Some(status.code().unwrap_or(-1));
            }
            if Instant::now() > end {
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGKILL and reap: a crash, as far as the rest of the graph can tell.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Sends signal `name` (`STOP`, `CONT`, `INT`, `TERM`, ...) with `kill`.
    pub fn signal(&self, name: &str) {
        let pid = self.pid();
        assert!(pid != 0, "{} has been reaped", self.name);
        let ok = Command::new("kill")
            .arg(format!("-{name}"))
            .arg(pid.to_string())
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill -{name} {pid} ({})", self.name);
    }

    /// SIGTERM, then wait for a clean exit; returns the exit code.
    pub fn terminate(&mut self, timeout: Duration) -> Option<i32> {
        let pid = self.pid();
        if pid == 0 {
            return None;
        }
        let _ = Command::new("kill")
            .arg("-TERM")
            .arg(pid.to_string())
            .status();
        self.wait_exit(timeout)
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

/// A stamp captured now on the wall clock: what a camera or a localisation
/// stack stamps, and what stages on the wall clock judge staleness by.
pub fn stamp_now(frame_seq: u64) -> farsight_interfaces::msg::Stamp {
    use farsight_interfaces::clock::Clock;
    farsight_interfaces::msg::Stamp::new(frame_seq, farsight_interfaces::clock::WallClock.now_ns())
}

/// The robot at the origin facing +x, as a localisation stack reports it now.
pub fn pose_now() -> farsight_interfaces::msg::Pose {
    farsight_interfaces::msg::Pose {
        stamp: stamp_now(0),
        ..Default::default()
    }
}

/// A memory cgroup for one test process: the limit a unit's `MemoryMax`
/// sets, with the peak use and whether the limit was hit. cgroup v1
/// (`/sys/fs/cgroup/memory`) or v2 (`/sys/fs/cgroup` with the memory
/// controller). systemd sets the same kernel limit for a unit; this stands
/// in for systemd, which does not run here.
pub struct MemoryCgroup {
    dir: PathBuf,
    v1: bool,
}

impl MemoryCgroup {
    /// A new cgroup limited to `limit_bytes`; panics naming what is missing
    /// if the machine has no writable memory cgroup (a test must not pass
    /// without its limit).
    pub fn new(name: &str, limit_bytes: u64) -> Self {
        let leaf = format!("farsight-test-{name}-{}", std::process::id());
        let v1_root = PathBuf::from("/sys/fs/cgroup/memory");
        let (dir, v1) = if v1_root.join("memory.limit_in_bytes").exists() {
            (v1_root.join(leaf), true)
        } else {
            (PathBuf::from("/sys/fs/cgroup").join(leaf), false)
        };
        std::fs::create_dir(&dir).unwrap_or_else(|e| {
            panic!(
                "memory cgroup {}: {e} (needs root and a memory cgroup)",
                dir.display()
            )
        });
        let limit = if v1 {
            "memory.limit_in_bytes"
        } else {
            "memory.max"
        };
        std::fs::write(dir.join(limit), limit_bytes.to_string())
            .unwrap_or_else(|e| panic!("{}: {e}", dir.join(limit).display()));
        Self { dir, v1 }
    }

    /// `cmd` wrapped so that it enters this cgroup before it execs: every
    /// allocation of the process is counted.
    pub fn wrap(&self, cmd: &Command) -> Command {
        let mut sh = Command::new("sh");
        sh.arg("-c")
            .arg(r#"echo $$ > "$FARSIGHT_CGROUP_PROCS" && exec "$@""#)
            .arg("sh")
            .arg(cmd.get_program())
            .args(cmd.get_args())
            .env("FARSIGHT_CGROUP_PROCS", self.dir.join("cgroup.procs"));
        for (k, v) in cmd.get_envs() {
            match v {
                Some(v) => sh.env(k, v),
                None => sh.env_remove(k),
            };
        }
        sh
    }

    fn read(&self, file: &str) -> String {
        std::fs::read_to_string(self.dir.join(file))
            .unwrap_or_else(|e| panic!("{}: {e}", self.dir.join(file).display()))
    }

    /// The most memory the cgroup's processes held at once, bytes.
    pub fn peak_bytes(&self) -> u64 {
        let f = if self.v1 {
            "memory.max_usage_in_bytes"
        } else {
            "memory.peak"
        };
        self.read(f).trim().parse().expect("a byte count")
    }

    /// How often an allocation hit the limit.
    pub fn limit_hits(&self) -> u64 {
        if self.v1 {
            self.read("memory.failcnt").trim().parse().expect("a count")
        } else {
            self.read("memory.events")
                .lines()
                .find_map(|l| l.strip_prefix("max "))
                .and_then(|n| n.trim().parse().ok())
                .unwrap_or(0)
        }
    }
}

impl Drop for MemoryCgroup {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir(&self.dir);
    }
}

/// A unit's `MemoryMax=` in bytes (`512M`, `1G`), read from
/// `deploy/systemd/farsight-<stage>.service`.
pub fn unit_memory_max_bytes(stage: &str) -> u64 {
    let path = repo_root().join(format!("deploy/systemd/farsight-{stage}.service"));
    let unit = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let value = unit
        .lines()
        .find_map(|l| l.trim().strip_prefix("MemoryMax="))
        .unwrap_or_else(|| panic!("{}: no MemoryMax=", path.display()));
    let (digits, unit_mult) = match value.trim().chars().last() {
        Some('K') => (&value[..value.len() - 1], 1u64 << 10),
        Some('M') => (&value[..value.len() - 1], 1 << 20),
        Some('G') => (&value[..value.len() - 1], 1 << 30),
        _ => (value, 1),
    };
    digits.trim().parse::<u64>().expect("MemoryMax digits") * unit_mult
}
