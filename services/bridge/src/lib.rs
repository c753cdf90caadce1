//! # farsight-bridge
//!
//! The link between the vehicle's shared-memory graph and other machines:
//! republishes chosen iceoryx2 topics on readable zenoh keys
//! (`farsight/<robot>/<topic>`), camera streams optionally downsampled and
//! JPEG/PNG-compressed, latest value only and at a capped rate; and imports
//! chosen zenoh keys (pose, goal, e-stop) into iceoryx2. A laptop or a second
//! computer talks to the robot only through it.
//!
//! Config (`bridge.toml`, every key optional; defaults shown):
//!
//! ```toml
//! robot = "robot"              # the <robot> segment of zenoh keys
//! health_rate_hz = 1.0
//! import_poll_hz = 100.0       # how often zenoh imports are checked
//!
//! [zenoh]
//! mode = "peer"                # "peer", "client" or "router"
//! listen = []                  # e.g. ["tcp/0.0.0.0:7447"]
//! connect = []                 # e.g. ["tcp/192.168.1.10:7447"]
//! config_file = ""             # a full zenoh json5 config (ACL, TLS); replaces the three keys above
//!                              # (the robot's router: `farsight-bridge --print-router-config`, see [`acl`])
//!
//! [[export]]                   # default exports: health and commands, no images
//! topic = "camera/front/image"
//! max_rate_hz = 5.0            # 0 = every message
//! downsample = 2               # images: keep every n-th pixel
//! compression = "jpeg"         # images: "none", "jpeg" or "png"
//! jpeg_quality = 80
//!
//! [[import]]                   # default imports: nav/goal, safety/estop (a topic is
//!                              # never both exported and imported: an echo loop; an
//!                              # operator's velocity commands come in as cmd/teleop, an
//!                              # input of farsight-command-mux, never as cmd/velocity)
//! topic = "nav/goal"
//! ```

use farsight_interfaces::msg::*;
use farsight_interfaces::topics::{self, kind_of, TopicKind};
use farsight_interfaces::transport::any::{AnyPublisher, AnySubscriber};
use farsight_interfaces::transport::ipc::{self, Bus};
use farsight_interfaces::transport::net::{NetBus, RawPublisher, RawSubscriber};
use farsight_interfaces::transport::{wire, TransportError};
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;

pub mod acl;

/// The bridge's config file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeConfig {
    pub robot: String,
    pub health_rate_hz: f64,
    pub import_poll_hz: f64,
    pub zenoh: ZenohConfig,
    pub export: Vec<ExportConfig>,
    pub import: Vec<ImportConfig>,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        Self {
            robot: "robot".into(),
            health_rate_hz: 1.0,
            import_poll_hz: 100.0,
            zenoh: ZenohConfig::default(),
            export: ["cmd/velocity", "nav/subgoal", "state/pose"]
                .iter()
                .map(|t| ExportConfig::plain(t))
                .collect(),
            import: ["nav/goal", "safety/estop"]
                .iter()
                .map(|t| ImportConfig {
                    topic: t.to_string(),
                })
                .collect(),
        }
    }
}

/// How the bridge joins zenoh.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    pub mode: String,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub config_file: String,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            mode: "peer".into(),
            listen: vec![],
            connect: vec![],
            config_file: String::new(),
        }
    }
}

impl ZenohConfig {
    /// The zenoh session config this describes; `base_dir` resolves a relative `config_file`.
    pub fn to_zenoh(&self, base_dir: &std::path::Path) -> Result<zenoh::Config, anyhow::Error> {
        if !self.config_file.is_empty() {
            let path = base_dir.join(&self.config_file);
            return zenoh::Config::from_file(&path)
                .map_err(|e| anyhow::anyhow!("zenoh.config_file {}: {e}", path.display()));
        }
        Ok(NetBus::config(&self.mode, &self.listen, &self.connect)?)
    }
}

/// How an image is compressed before it crosses the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Compression {
    #[default]
    None,
    Jpeg,
    Png,
}

/// One topic to republish on zenoh.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportConfig {
    pub topic: String,
    #[serde(default)]
    pub max_rate_hz: f64,
    #[serde(default = "one")]
    pub downsample: u32,
    #[serde(default)]
    pub compression: Compression,
    #[serde(default = "default_quality")]
    pub jpeg_quality: u8,
}

fn one() -> u32 {
    1
}
fn default_quality() -> u8 {
    80
}

impl ExportConfig {
    pub fn plain(topic: &str) -> Self {
        Self {
            topic: topic.to_string(),
            max_rate_hz: 0.0,
            downsample: 1,
            compression: Compression::None,
            jpeg_quality: 80,
        }
    }
}

/// One zenoh topic to bring into iceoryx2.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportConfig {
    pub topic: String,
}

impl farsight_stage::DeclaresTopics for BridgeConfig {
    fn topics(&self, instance: &str, _: &std::path::Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        // Exports forward what exists; imports are written from the network.
        for e in &self.export {
            io.read(e.topic.clone(), farsight_stage::Need::Optional);
        }
        for i in &self.import {
            io.write(i.topic.clone());
        }
        Ok(io)
    }
}

impl Validate for BridgeConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("health_rate_hz", self.health_rate_hz, RATE_HZ).key(
            "import_poll_hz",
            self.import_poll_hz,
            RATE_HZ,
        );
        for (i, e) in self.export.iter().enumerate() {
            // 0: every message.
            r.key(
                &format!("export[{i}].max_rate_hz"),
                e.max_rate_hz,
                Range::between(0.0, 1000.0).unit("Hz"),
            )
            .key(
                &format!("export[{i}].downsample"),
                e.downsample,
                Range::between(1.0, 64.0),
            )
            .key(
                &format!("export[{i}].jpeg_quality"),
                e.jpeg_quality,
                Range::between(1.0, 100.0),
            );
        }
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        topics::validate_name(&self.robot)
            .map_err(|e| ConfigError::invalid("robot", &self.robot, e.why))?;
        ConfigError::check(
            ["peer", "client", "router"].contains(&self.zenoh.mode.as_str()),
            "zenoh.mode",
            &self.zenoh.mode,
            "\"peer\", \"client\" or \"router\"",
        )?;
        for (i, e) in self.export.iter().enumerate() {
            let key = |k: &str| format!("export[{i}].{k}");
            let kind = kind_of(&e.topic).ok_or_else(|| {
                ConfigError::invalid(
                    key("topic"),
                    &e.topic,
                    "a farsight topic (see farsight_interfaces::topics)",
                )
            })?;
            if kind != TopicKind::Image && (e.downsample != 1 || e.compression != Compression::None)
            {
                return Err(ConfigError::invalid(
                    key("compression"),
                    format!("{:?} / downsample {}", e.compression, e.downsample),
                    "no compression or downsampling: only image topics can be compressed",
                ));
            }
        }
        for (i, im) in self.import.iter().enumerate() {
            match kind_of(&im.topic) {
                Some(k) if importable(k) => {}
                _ => {
                    return Err(ConfigError::invalid(
                        format!("import[{i}].topic"),
                        &im.topic,
                        "a fixed-size farsight topic (pose, goal, estop, velocity, health, camera info, subgoal, path, angular bins)",
                    ))
                }
            }
            // The base's topic has one writer, the command mux; an operator's
            // commands are one of its inputs, ranked, capped and e-stopped.
            if im.topic == topics::velocity_command().name() {
                return Err(ConfigError::invalid(
                    format!("import[{i}].topic"),
                    &im.topic,
                    "a command mux input such as \"cmd/teleop\": cmd/velocity has one writer, farsight-command-mux",
                ));
            }
            // Each message would come back in and go out again, without end.
            if self.export.iter().any(|e| e.topic == im.topic) {
                return Err(ConfigError::invalid(
                    format!("import[{i}].topic"),
                    &im.topic,
                    "a topic that is not also exported (an echo loop)",
                ));
            }
        }
        Ok(())
    }
}

fn importable(kind: TopicKind) -> bool {
    !matches!(
        kind,
        TopicKind::Image | TopicKind::Tensor | TopicKind::PolarBins | TopicKind::Costmap
    )
}

/// Turns a frame into what crosses the link: downsampled, maybe compressed.
pub fn transform_image(
    cfg: &ExportConfig,
    header: &ImageHeader,
    data: &[u8],
) -> Result<(ImageHeader, Vec<u8>), farsight_imaging::ImageError> {
    let (h, d) = if cfg.downsample > 1 {
        farsight_imaging::downsample(header, data, cfg.downsample)?
    } else {
        header.validate(data.len())?;
        (*header, data.to_vec())
    };
    let (encoding, bytes) = match cfg.compression {
        Compression::None => return Ok((h, d)),
        Compression::Jpeg => (
            PixelEncoding::JPEG,
            farsight_imaging::encode_jpeg(&h, &d, cfg.jpeg_quality)?,
        ),
        Compression::Png => (PixelEncoding::PNG, farsight_imaging::encode_png(&h, &d)?),
    };
    Ok((
        ImageHeader {
            encoding,
            stride_bytes: 0,
            ..h
        },
        bytes,
    ))
}

/// Counters of one export or import.
#[derive(Debug, Default, Clone, Copy)]
pub struct LinkStats {
    pub forwarded: u64,
    pub rate_limited: u64,
    pub failed: u64,
}

/// One exported topic: an iceoryx2 subscriber feeding a zenoh publisher.
pub struct Export {
    cfg: ExportConfig,
    source: AnySubscriber,
    out: RawPublisher,
    state: RefCell<(Option<u64>, LinkStats)>,
}

impl Export {
    pub fn open(bus: &Bus, net: &NetBus, cfg: ExportConfig) -> Result<Self, TransportError> {
        let name = cfg.topic.as_str();
        let kind = kind_of(name).ok_or_else(|| TransportError::Setting {
            key: "export.topic",
            value: name.into(),
            expected: "a farsight topic",
        })?;
        let source = AnySubscriber::open(bus, name)?;
        // Camera streams may be dropped under congestion; everything else must arrive.
        let out = net.bytes_publisher(name, kind == TopicKind::Image)?;
        Ok(Self {
            cfg,
            source,
            out,
            state: RefCell::new((None, LinkStats::default())),
        })
    }

    pub fn listener(&self) -> &ipc::InputListener {
        self.source.listener()
    }

    pub fn topic(&self) -> &str {
        &self.cfg.topic
    }

    pub fn stats(&self) -> LinkStats {
        self.state.borrow().1
    }

    /// Forwards the newest message, if any and if the rate cap allows.
    pub fn pump(&self, now_ns: u64) -> Result<bool, anyhow::Error> {
        let taken = match &self.source {
            AnySubscriber::Image(s) => match s.latest()? {
                None => None,
                Some(frame) => {
                    let (h, d) = transform_image(&self.cfg, frame.header(), frame.data())?;
                    let bytes = wire::encode_slice(&h, &d)?;
                    Some((h.stamp, bytes))
                }
            },
            other => other.take_wire()?,
        };
        let Some((_stamp, bytes)) = taken else {
            return Ok(false);
        };
        let mut st = self.state.borrow_mut();
        if self.cfg.max_rate_hz > 0.0 {
            let period = (1e9 / self.cfg.max_rate_hz) as u64;
            if st.0.is_some_and(|t| now_ns.saturating_sub(t) < period) {
                st.1.rate_limited += 1;
                return Ok(false);
            }
        }
        match self.out.put(bytes) {
            Ok(()) => {
                st.0 = Some(now_ns);
                st.1.forwarded += 1;
                Ok(true)
            }
            Err(e) => {
                st.1.failed += 1;
                Err(e.into())
            }
        }
    }
}

/// One imported topic: a zenoh subscriber feeding an iceoryx2 publisher.
pub struct Import {
    topic: String,
    input: RawSubscriber,
    sink: AnyPublisher,
    pub stats: LinkStats,
}

impl Import {
    pub fn open(bus: &Bus, net: &NetBus, cfg: &ImportConfig) -> Result<Self, TransportError> {
        let name = cfg.topic.as_str();
        if !kind_of(name).is_some_and(importable) {
            return Err(TransportError::Setting {
                key: "import.topic",
                value: name.into(),
                expected: "a fixed-size farsight topic",
            });
        }
        let sink = AnyPublisher::open(bus, name, 0)?;
        Ok(Self {
            topic: name.to_string(),
            input: net.bytes_subscriber(name)?,
            sink,
            stats: LinkStats::default(),
        })
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Moves the newest zenoh message (if any) into iceoryx2. A payload that
    /// does not decode is counted and reported, never forwarded.
    pub fn pump(&mut self) -> Result<bool, TransportError> {
        let Some(bytes) = self.input.try_latest()? else {
            self.sink.deliver_history()?;
            return Ok(false);
        };
        match self.sink.publish_wire(&bytes) {
            Ok(_) => {
                self.stats.forwarded += 1;
                Ok(true)
            }
            Err(e) => {
                self.stats.failed += 1;
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_errors_name_the_entry() {
        let e = farsight_stage::parse_config::<BridgeConfig>(
            "[[export]]\ntopic = \"nope/x\"",
            "b.toml",
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("config key `export[0].topic` = nope/x"),
            "{e}"
        );
        let e = farsight_stage::parse_config::<BridgeConfig>(
            "[[export]]\ntopic = \"cmd/velocity\"\ncompression = \"jpeg\"",
            "b.toml",
        )
        .unwrap_err();
        assert!(e.to_string().contains("only image topics"), "{e}");
        let e = farsight_stage::parse_config::<BridgeConfig>(
            "[[import]]\ntopic = \"camera/front/image\"",
            "b.toml",
        )
        .unwrap_err();
        assert!(e.to_string().contains("import[0].topic"), "{e}");
        let e = farsight_stage::parse_config::<BridgeConfig>(
            "[[export]]\ntopic = \"cmd/teleop\"\n[[import]]\ntopic = \"cmd/teleop\"",
            "b.toml",
        )
        .unwrap_err();
        assert!(e.to_string().contains("echo loop"), "{e}");
        let e = farsight_stage::parse_config::<BridgeConfig>(
            "[[import]]\ntopic = \"cmd/velocity\"",
            "b.toml",
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("import[0].topic") && e.to_string().contains("command-mux"),
            "{e}"
        );
        let ok =
            farsight_stage::parse_config::<BridgeConfig>("robot = \"husky1\"", "b.toml").unwrap();
        assert_eq!(ok.import.len(), 2);
    }

    #[test]
    fn image_export_downsamples_and_compresses() {
        let h = ImageHeader::packed(Stamp::new(9, 1), 0, 64, 32, PixelEncoding::RGB8);
        let d = vec![100u8; 64 * 32 * 3];
        let cfg = ExportConfig {
            downsample: 2,
            compression: Compression::Jpeg,
            ..ExportConfig::plain("camera/front/image")
        };
        let (oh, od) = transform_image(&cfg, &h, &d).unwrap();
        assert_eq!(
            (oh.width, oh.height, oh.encoding, oh.stamp),
            (32, 16, PixelEncoding::JPEG, h.stamp)
        );
        assert!(od.len() < 32 * 16 * 3);
        let (raw, _) = transform_image(&ExportConfig::plain("camera/front/image"), &h, &d).unwrap();
        assert_eq!(raw, h);
        assert!(transform_image(&cfg, &h, &d[1..]).is_err());
    }
}
