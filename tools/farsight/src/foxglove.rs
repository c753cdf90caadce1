//! `farsight foxglove`: watch the graph live in the Foxglove app.
//!
//! ```text
//! farsight foxglove                                      # on the robot: shared memory, ws://127.0.0.1:8765
//! farsight foxglove --connect tcp/ROBOT:7447 --robot r1  # on a laptop: the robot's bridge over zenoh
//! farsight foxglove --rate '/camera/*/image=2' --config deploy/config/foxglove.toml
//! ```
//!
//! Open Foxglove, "Open connection", `ws://HOST:PORT`, and import
//! `deploy/foxglove/farsight-layout.json` for camera, 3-D view, bins,
//! commanded velocity and stage health. The server is read-only.

use anyhow::{Context, Result};
use farsight_foxglove::{serve_shm, serve_zenoh, LiveServer, Rate, ServeOptions, View, ViewConfig};
use farsight_interfaces::transport::ipc::Bus;
use farsight_interfaces::transport::net::NetBus;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, clap::Args)]
pub struct FoxgloveArgs {
    /// Address to listen on. The protocol has no authentication: keep the
    /// default on a robot and reach it through zenoh from the laptop.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    /// Port to listen on (0: any free port, printed at start).
    #[arg(long, default_value_t = 8765)]
    pub port: u16,
    /// A TOML file with a [foxglove] table (image_max_width_px,
    /// jpeg_quality, [[foxglove.rate]] topic/hz); defaults fit 10 Mbit/s.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// A rate limit `TOPIC=HZ` on a Foxglove topic (glob), ahead of the
    /// config's rules; `=0` turns topics off. Repeatable.
    #[arg(long, value_parser = Rate::parse)]
    pub rate: Vec<Rate>,
    /// Serve a robot's bridge over zenoh instead of this machine's shared
    /// memory: the robot's zenoh endpoint(s), e.g. tcp/192.168.1.10:7447.
    #[arg(long, value_delimiter = ',')]
    pub connect: Vec<String>,
    /// With --connect: the robot's name (the <robot> of its zenoh keys).
    #[arg(long, default_value = "robot")]
    pub robot: String,
    #[command(flatten)]
    pub login: crate::Login,
    /// Stop after this many seconds (default: at Ctrl-C / SIGTERM).
    #[arg(long)]
    pub duration_s: Option<f64>,
}

#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ConfigFile {
    #[serde(default)]
    foxglove: ViewConfig,
}

/// The view's settings: the file's (or the defaults), command-line rates first.
pub fn view_config(file: Option<&std::path::Path>, rates: &[Rate]) -> Result<ViewConfig> {
    let mut config = match file {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            toml::from_str::<ConfigFile>(&text)
                .with_context(|| format!("{}", path.display()))?
                .foxglove
        }
        None => ViewConfig::default(),
    };
    config.rate.splice(0..0, rates.iter().cloned());
    config
        .validate()
        .map_err(|e| anyhow::anyhow!("foxglove config: {e}"))?;
    Ok(config)
}

pub fn run(a: FoxgloveArgs) -> Result<()> {
    let config = view_config(a.config.as_deref(), &a.rate)?;
    let mut view = View::new(config).map_err(|e| anyhow::anyhow!(e))?;
    let mut server = LiveServer::start(&a.host, a.port)?;
    let opts = ServeOptions {
        duration: a.duration_s.map(Duration::from_secs_f64),
        ..Default::default()
    };
    // The line a parent process (the demo, tests) waits for.
    println!(
        "farsight-foxglove ready ws://{}:{} (read-only)",
        a.host,
        server.port()
    );
    let result = if a.connect.is_empty() {
        serve_shm(
            &Bus::open("farsight-foxglove")?,
            &mut view,
            &mut server,
            &opts,
        )
    } else {
        let config = a.login.client_config("client", &a.connect)?;
        serve_zenoh(
            &NetBus::open(config, &a.robot)?,
            &mut view,
            &mut server,
            &opts,
        )
    };
    // The closing report; its reader (the demo) may be gone already, and a
    // closed stdout is no reason to fail.
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    for (topic, s) in server.stats() {
        let _ = writeln!(
            stdout,
            "{topic:<34} {:>8} messages {:>10.3} MB",
            s.messages,
            s.bytes as f64 / 1e6
        );
    }
    for (topic, n) in view.dropped() {
        let _ = writeln!(stdout, "{topic:<34} {n:>8} not shown (see the log)");
    }
    drop(stdout);
    server.stop();
    Ok(result?)
}
