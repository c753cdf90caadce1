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
//! commanded velocity and stage health.
//!
//! On the robot the server is read-only. On a laptop (`--connect`) it also
//! takes goals (the 3-D panel's publish tools, in frame `map`), teleop (the
//! Teleop panel) and the e-stop button from the app, and only when logged in
//! as the operator (`--user operator`, FARSIGHT_ZENOH_PASSWORD): anyone
//! else's are refused, logged and answered with a status the app shows. The
//! app's e-stop is a convenience, not a safety function (see
//! `farsight_foxglove::operator`). The config file's `[operator]` table
//! sets the teleop limits.

use anyhow::{Context, Result};
use farsight_foxglove::operator::may_command;
use farsight_foxglove::{
    serve_shm, serve_zenoh, LiveServer, OperatorConfig, OperatorInput, Rate, ServeOptions, View,
    ViewConfig,
};
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
    /// jpeg_quality, [[foxglove.rate]] topic/hz; defaults fit 10 Mbit/s)
    /// and an [operator] table (teleop limits, see farsight_foxglove::operator).
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
    #[serde(default)]
    operator: OperatorConfig,
}

fn config_file(file: Option<&std::path::Path>) -> Result<ConfigFile> {
    let Some(path) = file else {
        return Ok(ConfigFile::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let config =
        toml::from_str::<ConfigFile>(&text).with_context(|| format!("{}", path.display()))?;
    config
        .operator
        .validate()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(config)
}

/// The view's settings: the file's (or the defaults), command-line rates first.
fn view_config(mut config: ViewConfig, rates: &[Rate]) -> Result<ViewConfig> {
    config.rate.splice(0..0, rates.iter().cloned());
    config
        .validate()
        .map_err(|e| anyhow::anyhow!("foxglove config: {e}"))?;
    Ok(config)
}

pub fn run(a: FoxgloveArgs) -> Result<()> {
    let file = config_file(a.config.as_deref())?;
    let config = view_config(file.foxglove, &a.rate)?;
    let mut view = View::new(config).map_err(|e| anyhow::anyhow!(e))?;
    // The laptop's server takes the operator's messages; the robot's stays read-only.
    let operator = (!a.connect.is_empty()).then(|| OperatorInput {
        rights: may_command(a.login.user.as_deref(), farsight_bridge::acl::OPERATOR),
        config: file.operator,
        source: format!("foxglove {}", a.login.user.as_deref().unwrap_or("-")),
    });
    let mode = match &operator {
        None => "read-only".to_string(),
        Some(OperatorInput { rights: Ok(()), .. }) => "operator: goals, e-stop, teleop".into(),
        Some(OperatorInput {
            rights: Err(why), ..
        }) => {
            eprintln!(
                "farsight foxglove: the app's goals, e-stop and teleop will be refused: {why}"
            );
            "commands refused".into()
        }
    };
    let mut server = LiveServer::start_with(&a.host, a.port, operator)?;
    let opts = ServeOptions {
        duration: a.duration_s.map(Duration::from_secs_f64),
        ..Default::default()
    };
    // The line a parent process (the demo, tests) waits for.
    println!(
        "farsight-foxglove ready ws://{}:{} ({mode})",
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
    for (topic, s) in server.operator_stats() {
        let _ = writeln!(
            stdout,
            "{topic:<34} {:>8} from the app sent to the robot, {} refused",
            s.accepted, s.refused
        );
    }
    for (topic, n) in view.dropped() {
        let _ = writeln!(stdout, "{topic:<34} {n:>8} not shown (see the log)");
    }
    drop(stdout);
    server.stop();
    Ok(result?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped() -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/config/foxglove.toml")
    }

    #[test]
    fn the_shipped_config_is_the_defaults() {
        let file = config_file(Some(&shipped())).unwrap();
        assert_eq!(file.foxglove, ViewConfig::default());
        assert_eq!(file.operator, OperatorConfig::default());
    }

    #[test]
    fn a_bad_operator_limit_is_refused_naming_the_file_and_key() {
        let dir = std::env::temp_dir().join(format!("farsight-foxcfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("foxglove.toml");
        std::fs::write(&path, "[operator]\nteleop_max_linear_mps = -1.0\n").unwrap();
        let e = format!("{:#}", config_file(Some(&path)).err().unwrap());
        assert!(
            e.contains("foxglove.toml") && e.contains("`operator.teleop_max_linear_mps` = -1"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
