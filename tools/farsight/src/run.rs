//! `farsight run GRAPH`: starts this machine's nodes of a graph file as
//! processes and supervises them the way systemd supervises the robot's
//! units, with the same protocol (`sd_notify(3)`): each instance gets its own
//! `NOTIFY_SOCKET` and `WATCHDOG_USEC`; `READY=1` is announced, a stage that
//! stops pinging `WATCHDOG=1` after it was ready is killed, and an exit is
//! restarted by the node's policy (`no`, `on-failure`, `always`) with
//! back-off (0.5 s doubling to 10 s; reset after 30 s up). Sources (nodes
//! that need no input and feed others: camera drivers, players) start once
//! the other nodes are ready, so no first frame goes out unread. One log per
//! instance (`<out>/<instance>.log`); Ctrl-C or SIGTERM stops every node
//! (SIGTERM, then SIGKILL after 10 s).
//!
//! On the robot systemd supervises (`farsight.target`); off the robot
//! `farsight run` does; never both: it refuses to run under systemd, and
//! refuses a graph whose instances already report health in this
//! shared-memory namespace.

use crate::graph::{ConfigSource, Graph, NodeSpec, Restart};
use anyhow::{bail, Context, Result};
use farsight_interfaces::transport::ipc::{parse_queues, QUEUES_ENV};
use farsight_stage::Need;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// A graph file (graphs/*.toml).
    pub graph: PathBuf,
    /// Start the nodes whose `machine` is this.
    #[arg(long, default_value = "robot")]
    pub machine: String,
    /// Folder for each instance's log and its config when written inline.
    #[arg(long, default_value = "run")]
    pub out: PathBuf,
    /// Watchdog interval: a ready stage that does not ping for this long is
    /// killed and restarted (systemd's WatchdogSec=; the units use 10).
    #[arg(long, default_value_t = 10.0)]
    pub watchdog_s: f64,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
}

const BACKOFF_FIRST: Duration = Duration::from_millis(500);
const BACKOFF_MAX: Duration = Duration::from_secs(10);
/// Up this long, a node's back-off starts again from the first step.
const BACKOFF_RESET: Duration = Duration::from_secs(30);
const STOP_GRACE: Duration = Duration::from_secs(10);

/// One supervised instance.
struct Supervised {
    spec: NodeSpec,
    command: Command,
    log: PathBuf,
    notify: UnixDatagram,
    child: Option<Child>,
    started: Instant,
    ready: bool,
    last_ping: Instant,
    failures: u32,
    restart_at: Option<Instant>,
}

impl Supervised {
    fn start(&mut self) -> Result<()> {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("opening {}", self.log.display()))?;
        let child = self
            .command
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting {}", self.spec.name))?;
        println!("{}: started (pid {})", self.spec.name, child.id());
        self.child = Some(child);
        self.started = Instant::now();
        self.ready = false;
        self.restart_at = None;
        Ok(())
    }

    /// Reads the notify messages the stage sent.
    fn drain_notify(&mut self) {
        let mut buf = [0u8; 4096];
        while let Ok(n) = self.notify.recv(&mut buf) {
            for line in String::from_utf8_lossy(&buf[..n]).lines() {
                match line {
                    "READY=1" if !self.ready => {
                        self.ready = true;
                        self.last_ping = Instant::now();
                        println!("{}: ready", self.spec.name);
                    }
                    "WATCHDOG=1" => self.last_ping = Instant::now(),
                    _ => {}
                }
            }
        }
    }

    fn signal(&self, sig: libc::c_int) {
        if let Some(c) = &self.child {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(c.id() as libc::pid_t, sig) };
        }
    }

    /// Restarts due, exits noticed, watchdog enforced.
    fn supervise(&mut self, watchdog: Duration) -> Result<()> {
        self.drain_notify();
        if let Some(at) = self.restart_at {
            if Instant::now() >= at {
                self.start()?;
            }
            return Ok(());
        }
        let Some(child) = &mut self.child else {
            return Ok(());
        };
        if self.ready && self.last_ping.elapsed() > watchdog {
            println!(
                "{}: no watchdog ping for {:.1} s: killed",
                self.spec.name,
                self.last_ping.elapsed().as_secs_f64()
            );
            let _ = child.kill();
            // Once: the next turn sees it exit.
            self.ready = false;
        }
        let Some(status) = child.try_wait()? else {
            return Ok(());
        };
        self.child = None;
        let failed = !status.success();
        let restart = match self.spec.restart {
            Restart::No => false,
            Restart::OnFailure => failed,
            Restart::Always => true,
        };
        if self.started.elapsed() >= BACKOFF_RESET {
            self.failures = 0;
        }
        if !restart {
            println!(
                "{}: exited ({status}); restart = {:?}: left down",
                self.spec.name, self.spec.restart
            );
            return Ok(());
        }
        let delay = (BACKOFF_FIRST * 2u32.saturating_pow(self.failures)).min(BACKOFF_MAX);
        self.failures += 1;
        println!(
            "{}: exited ({status}); restart {} in {:.1} s (log: {})",
            self.spec.name,
            self.failures,
            delay.as_secs_f64(),
            self.log.display()
        );
        self.restart_at = Some(Instant::now() + delay);
        Ok(())
    }
}

/// The queues every node on `machine` declares to the transport: the
/// graph's queued edges there, and those this process was started with (a
/// demo's recorder outside the graph), the deeper where both name a topic.
fn queues_for(graph: &Graph, machine: &str) -> Result<String> {
    let inherited = std::env::var(QUEUES_ENV).unwrap_or_default();
    let mut all = parse_queues(&inherited)?;
    for (t, d) in parse_queues(&graph.queues(machine))? {
        let e = all.entry(t).or_insert(d);
        *e = (*e).max(d);
    }
    Ok(all
        .iter()
        .map(|(t, d)| format!("{t}={d}"))
        .collect::<Vec<_>>()
        .join(","))
}

/// The command that starts `spec` (the sibling binary `farsight-<stage>`).
pub(crate) fn node_command(spec: &NodeSpec, graph_dir: &Path, out: &Path) -> Result<Command> {
    let mut cmd = Command::new(crate::demo::sibling(&format!("farsight-{}", spec.stage))?);
    crate::demo::die_with_parent(&mut cmd);
    cmd.arg("--instance").arg(&spec.name).stdin(Stdio::null());
    match &spec.config {
        None => {}
        Some(ConfigSource::File(f)) => {
            cmd.arg("--config")
                .arg(std::path::absolute(graph_dir.join(f))?);
        }
        Some(ConfigSource::Inline(table)) => {
            let file = out.join(format!("{}.toml", spec.name));
            let text = format!(
                "# node `{}` of the graph file, written by farsight run; paths resolve\n# against the graph file's folder (--base-dir).\n{}",
                spec.name,
                toml::to_string(table)?
            );
            std::fs::write(&file, text).with_context(|| format!("writing {}", file.display()))?;
            cmd.arg("--config")
                .arg(&file)
                .arg("--base-dir")
                .arg(std::path::absolute(graph_dir)?);
        }
    }
    Ok(cmd)
}

/// Refuses to start instances that already run (under systemd, or another
/// `farsight run`): their health topics already carry reports.
fn refuse_running(nodes: &[&NodeSpec]) -> Result<()> {
    if std::env::var_os("INVOCATION_ID").is_some() {
        bail!("farsight run is running under systemd: on the robot, systemd supervises (farsight.target); never both");
    }
    use farsight_interfaces::topics;
    use farsight_interfaces::transport::ipc::Bus;
    let bus = Bus::open(&format!("farsight-run-{}", std::process::id()))?;
    let subs = nodes
        .iter()
        .map(|n| Ok((n.name.as_str(), bus.subscriber(&topics::health(&n.name))?)))
        .collect::<Result<Vec<_>>>()?;
    // Health goes out about once a second: wait a little longer.
    let end = Instant::now() + Duration::from_millis(1500);
    while Instant::now() < end {
        for (name, sub) in &subs {
            if let Some(h) = sub.latest()? {
                if h.state.name() != Some("stopping") {
                    bail!(
                        "`{name}` already runs here (pid {}, health/{name} is live): stop it first (systemctl stop farsight.target, or the other farsight run)",
                        h.pid
                    );
                }
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(())
}

pub fn run(a: RunArgs) -> Result<()> {
    let graph = Graph::load(&a.graph)?;
    let graph_dir = std::path::absolute(&a.graph)?
        .parent()
        .unwrap_or(Path::new("/"))
        .to_path_buf();
    let here: Vec<&NodeSpec> = graph
        .nodes
        .iter()
        .map(|n| &n.spec)
        .filter(|s| s.machine == a.machine)
        .collect();
    if here.is_empty() {
        bail!(
            "{}: no node has machine = {:?}",
            a.graph.display(),
            a.machine
        );
    }
    for n in graph.nodes.iter().filter(|n| n.spec.machine != a.machine) {
        println!("{}: on {}, not started here", n.spec.name, n.spec.machine);
    }
    refuse_running(&here)?;
    std::fs::create_dir_all(a.out.join("notify"))?;
    let out = std::path::absolute(&a.out)?;
    let watchdog = Duration::from_secs_f64(a.watchdog_s.max(0.1));

    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone())?;
    }
    let queues = queues_for(&graph, &a.machine)?;
    if !queues.is_empty() {
        println!("queues: {queues}");
    }
    let mut nodes = Vec::new();
    for spec in &here {
        let path = out.join("notify").join(format!("{}.sock", spec.name));
        let _ = std::fs::remove_file(&path);
        let notify =
            UnixDatagram::bind(&path).with_context(|| format!("binding {}", path.display()))?;
        notify.set_nonblocking(true)?;
        let mut command = node_command(spec, &graph_dir, &out)?;
        command
            .env(QUEUES_ENV, &queues)
            .env(farsight_recording::node::RUN_OUT_ENV, &out)
            .env("NOTIFY_SOCKET", &path)
            .env("WATCHDOG_USEC", watchdog.as_micros().to_string())
            .env_remove("WATCHDOG_PID");
        let mut s = Supervised {
            spec: (*spec).clone(),
            command,
            log: out.join(format!("{}.log", spec.name)),
            notify,
            child: None,
            started: Instant::now(),
            ready: false,
            last_ping: Instant::now(),
            failures: 0,
            restart_at: None,
        };
        if !is_source(&graph, &spec.name) {
            s.start()?;
        }
        nodes.push(s);
    }
    // Sources start once the rest are ready (or have had SOURCE_WAIT).
    let sources_due = Instant::now() + SOURCE_WAIT;
    let mut sources_started = false;
    let end = a
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    while !stop.load(Ordering::Relaxed) && end.is_none_or(|e| Instant::now() < e) {
        for n in &mut nodes {
            n.supervise(watchdog)?;
        }
        if !sources_started {
            let readers_ready = nodes.iter().all(|n| n.child.is_none() || n.ready);
            if readers_ready || Instant::now() >= sources_due {
                if !readers_ready {
                    println!(
                        "not every node is ready after {} s: starting the sources anyway",
                        SOURCE_WAIT.as_secs()
                    );
                }
                for n in nodes.iter_mut().filter(|n| is_source(&graph, &n.spec.name)) {
                    n.start()?;
                }
                sources_started = true;
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    println!("stopping {} nodes", nodes.len());
    for n in &nodes {
        n.signal(libc::SIGTERM);
    }
    let deadline = Instant::now() + STOP_GRACE;
    for n in &mut nodes {
        let Some(child) = &mut n.child else { continue };
        loop {
            if let Some(status) = child.try_wait()? {
                println!("{}: stopped ({status})", n.spec.name);
                break;
            }
            if Instant::now() > deadline {
                println!(
                    "{}: did not stop in {} s: killed",
                    n.spec.name,
                    STOP_GRACE.as_secs()
                );
                let _ = child.kill();
                let _ = child.wait();
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    Ok(())
}

/// How long `farsight run` waits for the other nodes to be ready before it
/// starts the sources anyway.
const SOURCE_WAIT: Duration = Duration::from_secs(30);

/// A node that needs no input and feeds another node (a camera driver, a
/// player): `farsight run` starts it once the rest of the machine's nodes
/// are ready, so its first frames have their readers (a frame published
/// before its reader subscribed is gone: image topics keep no history, and
/// a paced camera would wait out its pace timeout for the lost frame's
/// answer).
fn is_source(graph: &Graph, name: &str) -> bool {
    let needs = graph.topics.values().any(|e| {
        e.readers
            .iter()
            .any(|(r, need)| r == name && *need == Need::Required)
    });
    let feeds = graph
        .topics
        .values()
        .any(|e| e.writers.iter().any(|w| w == name) && e.readers.iter().any(|(r, _)| r != name));
    !needs && feeds
}

/// `farsight run GRAPH` as a child process in the shared-memory namespace
/// `prefix` with `queues` declared beside the graph's own (`topic=depth,...`:
/// a recorder outside the graph), its nodes' logs and configs in `out`; returns once every node
/// of machine `robot` has announced itself ready, or fails naming those
/// that did not (and their logs) within `timeout`. The graph stops when the
/// returned guard drops. What `farsight run` prints goes to `out/run.log`.
pub fn start_graph(
    graph: &Path,
    out: &Path,
    prefix: &str,
    queues: &str,
    timeout: Duration,
) -> Result<crate::demo::Stage> {
    use std::io::{BufRead, Write};
    let g = Graph::load(graph)?;
    let mut waiting: Vec<String> = g
        .nodes
        .iter()
        .filter(|n| n.spec.machine == "robot")
        .map(|n| n.spec.name.clone())
        .collect();
    std::fs::create_dir_all(out)?;
    let mut cmd = Command::new(std::env::current_exe()?);
    crate::demo::die_with_parent(&mut cmd);
    let mut child = cmd
        .arg("run")
        .arg(graph)
        .arg("--out")
        .arg(out)
        .env("FARSIGHT_IPC_PREFIX", prefix)
        .env(QUEUES_ENV, queues)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .context("starting farsight run")?;
    let stdout = child.stdout.take().expect("piped");
    let stderr = child.stderr.take().expect("piped");
    let guard = crate::demo::Stage(child);
    let log_path = out.join("run.log");
    let mut log = std::fs::File::create(&log_path)?;
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let err_tx = tx.clone();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            let _ = err_tx.send(line);
        }
    });
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    let end = Instant::now() + timeout;
    while !waiting.is_empty() {
        let left = end.saturating_duration_since(Instant::now());
        let line = match rx.recv_timeout(left) {
            Ok(line) => line,
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => bail!(
                "farsight run {} stopped before {} was ready; see {}",
                graph.display(),
                waiting.join(", "),
                log_path.display()
            ),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => bail!(
                "{}: {} not ready after {:.0} s; see {} and the nodes' logs in {}",
                graph.display(),
                waiting.join(", "),
                timeout.as_secs_f64(),
                log_path.display(),
                out.display()
            ),
        };
        writeln!(log, "{line}")?;
        if let Some(name) = line.strip_suffix(": ready") {
            waiting.retain(|w| w != name);
        } else if let Some((name, _)) = line.split_once(": exited") {
            bail!(
                "{}: node `{name}` exited before it was ready; see {}",
                graph.display(),
                out.join(format!("{name}.log")).display()
            );
        }
    }
    // The rest of what it says goes to the log as it comes.
    std::thread::spawn(move || {
        for line in rx {
            let _ = writeln!(log, "{line}");
        }
    });
    Ok(guard)
}
