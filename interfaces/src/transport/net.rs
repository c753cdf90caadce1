//! The same publish / latest-value subscribe API as [`super::ipc`], over zenoh,
//! for links between machines (robot <-> laptop, robot <-> second computer).
//!
//! Keys are readable: `farsight/<robot>/<topic>`. Payloads use the [`super::wire`]
//! format. Must-arrive data (commands, goals, health) uses congestion control
//! `Block`; camera streams use `Drop` so a slow laptop link never backs up the
//! robot.
//!
//! ```no_run
//! use farsight_interfaces::{msg::*, topics, transport::net::NetBus};
//!
//! let bus = NetBus::open(zenoh::Config::default(), "husky1")?;
//! let mut publisher = bus.publisher(&topics::goal())?;
//! let mut subscriber = bus.subscriber(&topics::goal())?;
//! publisher.publish(&NavGoal { kind: GoalKind::LOCAL, x_m: 50.0, ..Default::default() })?;
//! let goal = subscriber.recv_timeout(std::time::Duration::from_secs(1))?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use super::wire;
use super::{SkipCounter, Stamped, TransportError};
use crate::topics::{Slice, Topic};
use bytemuck::Pod;
use core::marker::PhantomData;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::time::Duration;
use zenoh::handlers::{RingChannel, RingChannelHandler};
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

/// A process's zenoh session, scoped to one robot's keys.
#[derive(Clone)]
pub struct NetBus {
    session: Session,
    robot: String,
}

fn z_err(what: &'static str, key: &str, e: impl core::fmt::Display) -> TransportError {
    TransportError::Zenoh {
        what,
        key: key.to_string(),
        detail: e.to_string(),
    }
}

impl NetBus {
    /// Opens a zenoh session for robot `robot`.
    pub fn open(config: zenoh::Config, robot: &str) -> Result<Self, TransportError> {
        crate::topics::validate_name(robot).map_err(|e| TransportError::Setting {
            key: "robot",
            value: robot.to_string(),
            expected: e.why,
        })?;
        let session = zenoh::open(config)
            .wait()
            .map_err(|e| z_err("open session", robot, e))?;
        Ok(Self {
            session,
            robot: robot.to_string(),
        })
    }

    /// A zenoh config for tests and local links: only the given endpoints, no
    /// multicast scouting (which would find unrelated peers on the machine).
    pub fn config(
        mode: &str,
        listen: &[String],
        connect: &[String],
    ) -> Result<zenoh::Config, TransportError> {
        let mut c = zenoh::Config::default();
        let set = |c: &mut zenoh::Config, k: &'static str, v: String| {
            c.insert_json5(k, &v).map_err(|e| TransportError::Setting {
                key: k,
                value: v,
                expected: if e.to_string().is_empty() {
                    "valid zenoh json5"
                } else {
                    "valid zenoh json5 (see zenoh's DEFAULT_CONFIG.json5)"
                },
            })
        };
        set(&mut c, "mode", format!("{mode:?}"))?;
        set(&mut c, "listen/endpoints", format!("{listen:?}"))?;
        set(&mut c, "connect/endpoints", format!("{connect:?}"))?;
        set(&mut c, "scouting/multicast/enabled", "false".into())?;
        Ok(c)
    }

    /// Adds user/password credentials (zenoh's `usrpwd` authentication) to
    /// `config`, for a robot whose router checks them (deploy/zenoh).
    pub fn with_credentials(
        mut config: zenoh::Config,
        user: &str,
        password: &str,
    ) -> Result<zenoh::Config, TransportError> {
        for (k, v) in [
            ("transport/auth/usrpwd/user", user),
            ("transport/auth/usrpwd/password", password),
        ] {
            config
                .insert_json5(k, &format!("{v:?}"))
                .map_err(|_| TransportError::Setting {
                    key: "zenoh credentials",
                    value: k.to_string(),
                    expected: "a user name and password",
                })?;
        }
        Ok(config)
    }

    pub fn session(&self) -> &Session {
        &self.session
    }

    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// The zenoh key of `topic` on this bus's robot.
    pub fn key(&self, topic: &str) -> String {
        crate::topics::zenoh_key(&self.robot, topic)
    }

    fn raw_publisher(
        &self,
        topic: &str,
        congestion: CongestionControl,
    ) -> Result<RawPublisher, TransportError> {
        let key = self.key(topic);
        let publisher = self
            .session
            .declare_publisher(key.clone())
            .congestion_control(congestion)
            .wait()
            .map_err(|e| z_err("declare publisher", &key, e))?;
        Ok(RawPublisher { publisher, key })
    }

    /// A publisher of raw wire bytes on `topic` (used by the bridge).
    pub fn bytes_publisher(
        &self,
        topic: &str,
        drop_when_congested: bool,
    ) -> Result<RawPublisher, TransportError> {
        let cc = if drop_when_congested {
            CongestionControl::Drop
        } else {
            CongestionControl::Block
        };
        self.raw_publisher(topic, cc)
    }

    /// A latest-value subscriber of raw wire bytes on `topic`.
    pub fn bytes_subscriber(&self, topic: &str) -> Result<RawSubscriber, TransportError> {
        let key = self.key(topic);
        let subscriber = self
            .session
            .declare_subscriber(key.clone())
            .with(RingChannel::new(1))
            .wait()
            .map_err(|e| z_err("declare subscriber", &key, e))?;
        Ok(RawSubscriber { subscriber, key })
    }

    /// Every topic of this bus's robot (`farsight/<robot>/**`), with a queue
    /// of `capacity` messages so a recorder that falls briefly behind loses
    /// nothing (older messages go first when the queue is full).
    pub fn tap(&self, capacity: usize) -> Result<Tap, TransportError> {
        let key = format!("{}/{}/**", crate::topics::ROOT, self.robot);
        let subscriber = self
            .session
            .declare_subscriber(key.clone())
            .with(RingChannel::new(capacity.max(1)))
            .wait()
            .map_err(|e| z_err("declare subscriber", &key, e))?;
        Ok(Tap { subscriber, key })
    }

    /// A publisher of fixed-size messages (congestion control `Block`).
    pub fn publisher<M: Serialize>(
        &self,
        topic: &Topic<M>,
    ) -> Result<Publisher<M>, TransportError> {
        Ok(Publisher {
            raw: self.raw_publisher(topic.name(), CongestionControl::Block)?,
            _m: PhantomData,
        })
    }

    /// A latest-value subscriber of fixed-size messages.
    pub fn subscriber<M: DeserializeOwned + Stamped>(
        &self,
        topic: &Topic<M>,
    ) -> Result<Subscriber<M>, TransportError> {
        Ok(Subscriber {
            raw: self.bytes_subscriber(topic.name())?,
            skips: SkipCounter::default(),
            _m: PhantomData,
        })
    }

    /// A publisher of header + slice messages. `drop_when_congested` suits
    /// camera streams; maps and paths should block instead.
    pub fn slice_publisher<H: Serialize, E: Pod>(
        &self,
        topic: &Topic<Slice<H, E>>,
        drop_when_congested: bool,
    ) -> Result<SlicePublisher<H, E>, TransportError> {
        Ok(SlicePublisher {
            raw: self.bytes_publisher(topic.name(), drop_when_congested)?,
            _m: PhantomData,
        })
    }

    /// A latest-value subscriber of header + slice messages.
    pub fn slice_subscriber<H: DeserializeOwned + Stamped, E: Pod>(
        &self,
        topic: &Topic<Slice<H, E>>,
    ) -> Result<SliceSubscriber<H, E>, TransportError> {
        Ok(SliceSubscriber {
            raw: self.bytes_subscriber(topic.name())?,
            skips: SkipCounter::default(),
            _m: PhantomData,
        })
    }
}

/// Publishes already-encoded bytes on one key.
pub struct RawPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
    key: String,
}

impl RawPublisher {
    pub fn put(&self, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.publisher
            .put(bytes)
            .wait()
            .map_err(|e| z_err("put", &self.key, e))
    }

    pub fn key(&self) -> &str {
        &self.key
    }
}

/// Receives every topic of one robot, in arrival order.
pub struct Tap {
    subscriber: zenoh::pubsub::Subscriber<RingChannelHandler<Sample>>,
    key: String,
}

impl Tap {
    /// The next message, as (topic, wire bytes), if one is queued.
    pub fn try_next(&self) -> Result<Option<(String, Vec<u8>)>, TransportError> {
        while let Some(s) = self
            .subscriber
            .try_recv()
            .map_err(|e| z_err("receive", &self.key, e))?
        {
            if let Some((_, topic)) = crate::topics::parse_zenoh_key(s.key_expr().as_str()) {
                return Ok(Some((
                    topic.to_string(),
                    s.payload().to_bytes().into_owned(),
                )));
            }
        }
        Ok(None)
    }
}

/// Receives the newest bytes on one key.
pub struct RawSubscriber {
    subscriber: zenoh::pubsub::Subscriber<RingChannelHandler<Sample>>,
    key: String,
}

impl RawSubscriber {
    /// The newest payload since the last call, without waiting.
    pub fn try_latest(&self) -> Result<Option<Vec<u8>>, TransportError> {
        let mut newest = None;
        while let Some(s) = self
            .subscriber
            .try_recv()
            .map_err(|e| z_err("receive", &self.key, e))?
        {
            newest = Some(s.payload().to_bytes().into_owned());
        }
        Ok(newest)
    }

    /// Waits up to `timeout` for a payload.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<Vec<u8>>, TransportError> {
        Ok(self
            .subscriber
            .recv_timeout(timeout)
            .map_err(|e| z_err("receive", &self.key, e))?
            .map(|s| s.payload().to_bytes().into_owned()))
    }

    pub fn key(&self) -> &str {
        &self.key
    }
}

/// zenoh counterpart of [`super::ipc::Publisher`].
pub struct Publisher<M> {
    raw: RawPublisher,
    _m: PhantomData<fn(M)>,
}

impl<M: Serialize> Publisher<M> {
    pub fn publish(&mut self, msg: &M) -> Result<(), TransportError> {
        let bytes = wire::encode_message(msg).map_err(|source| TransportError::Decode {
            topic: self.raw.key.clone(),
            source,
        })?;
        self.raw.put(bytes)
    }
}

/// zenoh counterpart of [`super::ipc::Subscriber`].
pub struct Subscriber<M> {
    raw: RawSubscriber,
    skips: SkipCounter,
    _m: PhantomData<fn() -> M>,
}

impl<M: DeserializeOwned + Stamped> Subscriber<M> {
    fn decode(&mut self, bytes: Vec<u8>) -> Result<M, TransportError> {
        let m: M = wire::decode_message(&bytes).map_err(|source| TransportError::Decode {
            topic: self.raw.key.clone(),
            source,
        })?;
        self.skips.observe(m.stamp().frame_seq);
        Ok(m)
    }

    /// The newest message since the last call, if any.
    pub fn latest(&mut self) -> Result<Option<M>, TransportError> {
        match self.raw.try_latest()? {
            Some(b) => self.decode(b).map(Some),
            None => Ok(None),
        }
    }

    /// Waits up to `timeout` for a message.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<M>, TransportError> {
        match self.raw.recv_timeout(timeout)? {
            Some(b) => self.decode(b).map(Some),
            None => Ok(None),
        }
    }

    pub fn skips(&self) -> SkipCounter {
        self.skips
    }
}

/// zenoh counterpart of [`super::ipc::SlicePublisher`].
pub struct SlicePublisher<H, E> {
    raw: RawPublisher,
    _m: PhantomData<fn(H, E)>,
}

impl<H: Serialize, E: Pod> SlicePublisher<H, E> {
    pub fn publish(&mut self, header: &H, data: &[E]) -> Result<(), TransportError> {
        let bytes = wire::encode_slice(header, data).map_err(|source| TransportError::Decode {
            topic: self.raw.key.clone(),
            source,
        })?;
        self.raw.put(bytes)
    }
}

/// zenoh counterpart of [`super::ipc::SliceSubscriber`]; the data is copied out
/// of the network buffer.
pub struct SliceSubscriber<H, E> {
    raw: RawSubscriber,
    skips: SkipCounter,
    _m: PhantomData<fn() -> (H, E)>,
}

impl<H: DeserializeOwned + Stamped, E: Pod> SliceSubscriber<H, E> {
    fn decode(&mut self, bytes: Vec<u8>) -> Result<(H, Vec<E>), TransportError> {
        let (h, d): (H, Vec<E>) =
            wire::decode_slice(&bytes).map_err(|source| TransportError::Decode {
                topic: self.raw.key.clone(),
                source,
            })?;
        self.skips.observe(h.stamp().frame_seq);
        Ok((h, d))
    }

    pub fn latest(&mut self) -> Result<Option<(H, Vec<E>)>, TransportError> {
        match self.raw.try_latest()? {
            Some(b) => self.decode(b).map(Some),
            None => Ok(None),
        }
    }

    pub fn recv_timeout(
        &mut self,
        timeout: Duration,
    ) -> Result<Option<(H, Vec<E>)>, TransportError> {
        match self.raw.recv_timeout(timeout)? {
            Some(b) => self.decode(b).map(Some),
            None => Ok(None),
        }
    }

    pub fn skips(&self) -> SkipCounter {
        self.skips
    }
}
