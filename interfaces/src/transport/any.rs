//! Ports for topics known only by name at run time: the bridge, the recorder
//! and the replayer move any farsight topic without a type parameter. The
//! topic's name picks the message type ([`crate::topics::kind_of`]); what
//! crosses the port is the [`super::wire`] encoding, so the bytes a recorder
//! stores are the bytes the bridge sends over zenoh.
//!
//! ```no_run
//! use farsight_interfaces::transport::any::{AnyPublisher, AnySubscriber};
//! use farsight_interfaces::transport::ipc::Bus;
//!
//! let bus = Bus::open("tap")?;
//! let pose = AnySubscriber::open(&bus, "state/pose")?;
//! let mut copy = AnyPublisher::open(&bus, "state/pose", 0)?;
//! if let Some((stamp, bytes)) = pose.take_wire()? {
//!     copy.publish_wire(&bytes)?;
//!     println!("forwarded frame {}", stamp.frame_seq);
//! }
//! # Ok::<(), farsight_interfaces::transport::TransportError>(())
//! ```

use super::ipc::{Bus, InputListener, IpcHeader, IpcMessage, Publisher, SlicePublisher};
use super::ipc::{SliceSubscriber, Subscriber};
use super::{wire, SkipCounter, TransportError};
use crate::message::{Message, Sliced};
use crate::msg::*;
use crate::topics::{kind_of, Slice, Topic, TopicKind};
use serde::de::DeserializeOwned;
use serde::Serialize;

fn topic<M: ?Sized>(name: &str) -> Result<Topic<M>, TransportError> {
    Topic::new(name).map_err(|e| TransportError::Setting {
        key: "topic",
        value: name.into(),
        expected: e.why,
    })
}

fn kind(name: &str) -> Result<TopicKind, TransportError> {
    kind_of(name).ok_or_else(|| TransportError::Setting {
        key: "topic",
        value: name.into(),
        expected: "a farsight topic (see farsight_interfaces::topics)",
    })
}

fn wrong_kind(topic: &str, m: &Message) -> TransportError {
    TransportError::Setting {
        key: "message",
        value: format!("{:?} on {topic}", m.kind()),
        expected: "a message of the topic's own kind",
    }
}

fn decode_err(topic: &str) -> impl FnOnce(wire::WireError) -> TransportError + '_ {
    move |source| TransportError::Decode {
        topic: topic.to_string(),
        source,
    }
}

/// The stamp of one wire-encoded message of `topic`, read without decoding
/// the payload of header+slice messages.
pub fn wire_stamp(topic: &str, bytes: &[u8]) -> Result<Stamp, TransportError> {
    fn fixed<M: DeserializeOwned + super::Stamped>(
        t: &str,
        b: &[u8],
    ) -> Result<Stamp, TransportError> {
        Ok(wire::decode_message::<M>(b).map_err(decode_err(t))?.stamp())
    }
    fn header<H: DeserializeOwned + super::Stamped>(
        t: &str,
        b: &[u8],
    ) -> Result<Stamp, TransportError> {
        Ok(wire::split_slice::<H>(b).map_err(decode_err(t))?.0.stamp())
    }
    match kind(topic)? {
        TopicKind::Image => header::<ImageHeader>(topic, bytes),
        TopicKind::Tensor => header::<TensorHeader>(topic, bytes),
        TopicKind::PolarBins => header::<PolarBinsHeader>(topic, bytes),
        TopicKind::Costmap => header::<CostmapHeader>(topic, bytes),
        TopicKind::CameraInfo => fixed::<CameraInfo>(topic, bytes),
        TopicKind::AngularBins => fixed::<AngularBins>(topic, bytes),
        TopicKind::Subgoal => fixed::<Subgoal>(topic, bytes),
        TopicKind::Path => fixed::<Path>(topic, bytes),
        TopicKind::Goal => fixed::<NavGoal>(topic, bytes),
        TopicKind::Pose => fixed::<Pose>(topic, bytes),
        TopicKind::VelocityCommand => fixed::<VelocityCommand>(topic, bytes),
        TopicKind::EStop => fixed::<EStop>(topic, bytes),
        TopicKind::Health => fixed::<StageHealth>(topic, bytes),
    }
}

/// A fixed-size message subscriber behind a trait object.
pub trait FixedSubscriber {
    fn listener(&self) -> &InputListener;
    fn take_wire(&self) -> Result<Option<(Stamp, Vec<u8>)>, TransportError>;
    fn take_message(&self) -> Result<Option<Message>, TransportError>;
    /// Every message waiting, oldest first, wire-encoded with its stamp.
    fn take_all_wire(&self) -> Result<Vec<(Stamp, Vec<u8>)>, TransportError>;
    /// The newest message's stamp since the last call, nothing encoded.
    fn take_stamp(&self) -> Result<Option<Stamp>, TransportError>;
    fn skips(&self) -> SkipCounter;
}

impl<M: IpcMessage + Serialize + Into<Message>> FixedSubscriber for Subscriber<M> {
    fn listener(&self) -> &InputListener {
        Subscriber::listener(self)
    }
    fn take_wire(&self) -> Result<Option<(Stamp, Vec<u8>)>, TransportError> {
        match self.latest()? {
            None => Ok(None),
            Some(m) => {
                let bytes = wire::encode_message(&m).map_err(decode_err(self.topic()))?;
                Ok(Some((m.stamp(), bytes)))
            }
        }
    }
    fn take_message(&self) -> Result<Option<Message>, TransportError> {
        Ok(self.latest()?.map(Into::into))
    }
    fn take_stamp(&self) -> Result<Option<Stamp>, TransportError> {
        Ok(self.latest()?.map(|m| m.stamp()))
    }
    fn take_all_wire(&self) -> Result<Vec<(Stamp, Vec<u8>)>, TransportError> {
        self.drain()?
            .into_iter()
            .map(|m| {
                let bytes = wire::encode_message(&m).map_err(decode_err(self.topic()))?;
                Ok((m.stamp(), bytes))
            })
            .collect()
    }
    fn skips(&self) -> SkipCounter {
        Subscriber::skips(self)
    }
}

/// The latest-value subscriber of any topic, by kind.
pub enum AnySubscriber {
    Image(SliceSubscriber<ImageHeader, u8>),
    Tensor(SliceSubscriber<TensorHeader, f32>),
    Polar(SliceSubscriber<PolarBinsHeader, PolarCell>),
    Costmap(SliceSubscriber<CostmapHeader, CostCell>),
    Fixed(Box<dyn FixedSubscriber>),
}

fn fixed_sub<M: IpcMessage + Serialize + Into<Message>>(
    bus: &Bus,
    name: &str,
    queued: bool,
) -> Result<AnySubscriber, TransportError> {
    let t = topic::<M>(name)?;
    let sub = if queued {
        bus.queue_subscriber(&t)?
    } else {
        bus.subscriber(&t)?
    };
    Ok(AnySubscriber::Fixed(Box::new(sub)))
}

fn slice_sub<H: IpcHeader, E: super::ipc::IpcElem>(
    bus: &Bus,
    name: &str,
    queued: bool,
) -> Result<SliceSubscriber<H, E>, TransportError> {
    let t = topic::<Slice<H, E>>(name)?;
    if queued {
        bus.queue_slice_subscriber(&t)
    } else {
        bus.slice_subscriber(&t)
    }
}

fn slice_all_wire<H: IpcHeader + Serialize, E: super::ipc::IpcElem>(
    sub: &SliceSubscriber<H, E>,
) -> Result<Vec<(Stamp, Vec<u8>)>, TransportError> {
    // At most a queue's worth per call (see `Subscriber::drain`): frames
    // are megabytes, and a publisher that keeps pace would grow this
    // without end.
    let mut out = Vec::new();
    while out.len() < sub.buffer_size() {
        let Some(s) = sub.next()? else { break };
        let bytes = wire::encode_slice(s.header(), s.data()).map_err(decode_err(sub.topic()))?;
        out.push((s.header().stamp(), bytes));
    }
    Ok(out)
}

fn slice_wire<H: IpcHeader + Serialize, E: super::ipc::IpcElem>(
    sub: &SliceSubscriber<H, E>,
) -> Result<Option<(Stamp, Vec<u8>)>, TransportError> {
    match sub.latest()? {
        None => Ok(None),
        Some(s) => {
            let bytes =
                wire::encode_slice(s.header(), s.data()).map_err(decode_err(sub.topic()))?;
            Ok(Some((s.header().stamp(), bytes)))
        }
    }
}

impl AnySubscriber {
    /// Subscribes to the topic `name` (latest-value); an unknown name is
    /// refused, naming it.
    pub fn open(bus: &Bus, name: &str) -> Result<Self, TransportError> {
        Self::open_as(bus, name, false)
    }

    /// Subscribes to the queue of topic `name` (every message, in order;
    /// see [`Bus::queue_subscriber`]); refused where none is declared.
    pub fn open_queued(bus: &Bus, name: &str) -> Result<Self, TransportError> {
        Self::open_as(bus, name, true)
    }

    fn open_as(bus: &Bus, name: &str, q: bool) -> Result<Self, TransportError> {
        Ok(match kind(name)? {
            TopicKind::Image => Self::Image(slice_sub(bus, name, q)?),
            TopicKind::Tensor => Self::Tensor(slice_sub(bus, name, q)?),
            TopicKind::PolarBins => Self::Polar(slice_sub(bus, name, q)?),
            TopicKind::Costmap => Self::Costmap(slice_sub(bus, name, q)?),
            TopicKind::CameraInfo => fixed_sub::<CameraInfo>(bus, name, q)?,
            TopicKind::AngularBins => fixed_sub::<AngularBins>(bus, name, q)?,
            TopicKind::Subgoal => fixed_sub::<Subgoal>(bus, name, q)?,
            TopicKind::Path => fixed_sub::<Path>(bus, name, q)?,
            TopicKind::Goal => fixed_sub::<NavGoal>(bus, name, q)?,
            TopicKind::Pose => fixed_sub::<Pose>(bus, name, q)?,
            TopicKind::VelocityCommand => fixed_sub::<VelocityCommand>(bus, name, q)?,
            TopicKind::EStop => fixed_sub::<EStop>(bus, name, q)?,
            TopicKind::Health => fixed_sub::<StageHealth>(bus, name, q)?,
        })
    }

    /// Every message waiting, oldest first, wire-encoded with its stamp:
    /// on a queue subscriber each message sent since the last call; on a
    /// latest-value one at most the newest.
    pub fn take_all_wire(&self) -> Result<Vec<(Stamp, Vec<u8>)>, TransportError> {
        match self {
            Self::Image(s) => slice_all_wire(s),
            Self::Tensor(s) => slice_all_wire(s),
            Self::Polar(s) => slice_all_wire(s),
            Self::Costmap(s) => slice_all_wire(s),
            Self::Fixed(s) => s.take_all_wire(),
        }
    }

    /// The listener to attach to a WaitSet.
    pub fn listener(&self) -> &InputListener {
        match self {
            Self::Image(s) => s.listener(),
            Self::Tensor(s) => s.listener(),
            Self::Polar(s) => s.listener(),
            Self::Costmap(s) => s.listener(),
            Self::Fixed(s) => s.listener(),
        }
    }

    /// The newest message since the last call, wire-encoded, with its stamp.
    pub fn take_wire(&self) -> Result<Option<(Stamp, Vec<u8>)>, TransportError> {
        match self {
            Self::Image(s) => slice_wire(s),
            Self::Tensor(s) => slice_wire(s),
            Self::Polar(s) => slice_wire(s),
            Self::Costmap(s) => slice_wire(s),
            Self::Fixed(s) => s.take_wire(),
        }
    }

    /// The newest message's stamp since the last call, read in shared
    /// memory: a tap that times frames copies none of them.
    pub fn take_stamp(&self) -> Result<Option<Stamp>, TransportError> {
        fn header<H: IpcHeader, E: super::ipc::IpcElem>(
            sub: &SliceSubscriber<H, E>,
        ) -> Result<Option<Stamp>, TransportError> {
            Ok(sub.latest()?.map(|s| s.header().stamp()))
        }
        match self {
            Self::Image(s) => header(s),
            Self::Tensor(s) => header(s),
            Self::Polar(s) => header(s),
            Self::Costmap(s) => header(s),
            Self::Fixed(s) => s.take_stamp(),
        }
    }

    /// The newest message since the last call, copied out of shared memory.
    pub fn take_message(&self) -> Result<Option<Message>, TransportError> {
        fn sliced<H: IpcHeader, E: super::ipc::IpcElem>(
            sub: &SliceSubscriber<H, E>,
        ) -> Result<Option<Sliced<H, E>>, TransportError> {
            Ok(sub.latest()?.map(|s| Sliced {
                header: *s.header(),
                data: s.data().to_vec(),
            }))
        }
        Ok(match self {
            Self::Image(s) => sliced(s)?.map(Message::Image),
            Self::Tensor(s) => sliced(s)?.map(Message::Tensor),
            Self::Polar(s) => sliced(s)?.map(Message::PolarBins),
            Self::Costmap(s) => sliced(s)?.map(Message::Costmap),
            Self::Fixed(s) => s.take_message()?,
        })
    }

    /// Messages latest-value delivery skipped (gaps in the sequence numbers).
    pub fn skips(&self) -> SkipCounter {
        match self {
            Self::Image(s) => s.skips(),
            Self::Tensor(s) => s.skips(),
            Self::Polar(s) => s.skips(),
            Self::Costmap(s) => s.skips(),
            Self::Fixed(s) => s.skips(),
        }
    }
}

/// A fixed-size message publisher behind a trait object.
pub trait FixedPublisher {
    fn publish_wire(&mut self, bytes: &[u8]) -> Result<Stamp, TransportError>;
    /// Publishes an owned message; one of another type is refused.
    fn publish_message(&mut self, msg: Message) -> Result<(), TransportError>;
    /// Hands the last message to subscribers that joined since.
    fn deliver_history(&self) -> Result<(), TransportError>;
}

impl<M: IpcMessage + DeserializeOwned + TryFrom<Message, Error = Message>> FixedPublisher
    for Publisher<M>
{
    fn publish_wire(&mut self, bytes: &[u8]) -> Result<Stamp, TransportError> {
        let m: M = wire::decode_message(bytes).map_err(decode_err(self.topic()))?;
        self.publish(&m)?;
        Ok(m.stamp())
    }
    fn publish_message(&mut self, msg: Message) -> Result<(), TransportError> {
        let topic = self.topic().to_string();
        self.publish(&M::try_from(msg).map_err(|m| wrong_kind(&topic, &m))?)
    }
    fn deliver_history(&self) -> Result<(), TransportError> {
        Publisher::deliver_history(self)
    }
}

/// The publisher of any topic, by kind, fed wire-encoded messages.
pub enum AnyPublisher {
    Image(SlicePublisher<ImageHeader, u8>),
    Tensor(SlicePublisher<TensorHeader, f32>),
    Polar(SlicePublisher<PolarBinsHeader, PolarCell>),
    Costmap(SlicePublisher<CostmapHeader, CostCell>),
    Fixed(Box<dyn FixedPublisher>),
}

fn fixed_pub<M: IpcMessage + DeserializeOwned + TryFrom<Message, Error = Message>>(
    bus: &Bus,
    name: &str,
) -> Result<AnyPublisher, TransportError> {
    Ok(AnyPublisher::Fixed(Box::new(
        bus.publisher(&topic::<M>(name)?)?,
    )))
}

fn publish_slice<H: IpcHeader + DeserializeOwned, E: super::ipc::IpcElem>(
    p: &SlicePublisher<H, E>,
    bytes: &[u8],
) -> Result<Stamp, TransportError> {
    let (header, body) = wire::split_slice::<H>(bytes).map_err(decode_err(p.topic()))?;
    let elem = core::mem::size_of::<E>();
    if body.len() % elem != 0 {
        return Err(decode_err(p.topic())(wire::WireError::RaggedSlice {
            len: body.len(),
            elem,
        }));
    }
    // Copied straight into the shared-memory sample, which is aligned for E.
    p.publish_with(body.len() / elem, |out| {
        bytemuck::cast_slice_mut::<E, u8>(out).copy_from_slice(body);
        header
    })?;
    Ok(header.stamp())
}

impl AnyPublisher {
    /// A publisher for the topic `name`. Slice topics (images, tensors,
    /// bins, costmaps) allocate room for `max_slice_bytes` of elements up
    /// front; fixed-size topics ignore it.
    pub fn open(bus: &Bus, name: &str, max_slice_bytes: usize) -> Result<Self, TransportError> {
        let elems = |size: usize| (max_slice_bytes / size).max(1);
        Ok(match kind(name)? {
            TopicKind::Image => {
                Self::Image(bus.slice_publisher(&topic::<Slice<_, _>>(name)?, elems(1))?)
            }
            TopicKind::Tensor => {
                Self::Tensor(bus.slice_publisher(&topic::<Slice<_, _>>(name)?, elems(4))?)
            }
            TopicKind::PolarBins => Self::Polar(bus.slice_publisher(
                &topic::<Slice<_, _>>(name)?,
                elems(core::mem::size_of::<PolarCell>()),
            )?),
            TopicKind::Costmap => Self::Costmap(bus.slice_publisher(
                &topic::<Slice<_, _>>(name)?,
                elems(core::mem::size_of::<CostCell>()),
            )?),
            TopicKind::CameraInfo => fixed_pub::<CameraInfo>(bus, name)?,
            TopicKind::AngularBins => fixed_pub::<AngularBins>(bus, name)?,
            TopicKind::Subgoal => fixed_pub::<Subgoal>(bus, name)?,
            TopicKind::Path => fixed_pub::<Path>(bus, name)?,
            TopicKind::Goal => fixed_pub::<NavGoal>(bus, name)?,
            TopicKind::Pose => fixed_pub::<Pose>(bus, name)?,
            TopicKind::VelocityCommand => fixed_pub::<VelocityCommand>(bus, name)?,
            TopicKind::EStop => fixed_pub::<EStop>(bus, name)?,
            TopicKind::Health => fixed_pub::<StageHealth>(bus, name)?,
        })
    }

    /// Decodes one wire-encoded message and publishes it; returns its stamp.
    /// Bytes that do not decode as this topic's type are refused, naming it.
    pub fn publish_wire(&mut self, bytes: &[u8]) -> Result<Stamp, TransportError> {
        match self {
            Self::Image(p) => publish_slice(p, bytes),
            Self::Tensor(p) => publish_slice(p, bytes),
            Self::Polar(p) => publish_slice(p, bytes),
            Self::Costmap(p) => publish_slice(p, bytes),
            Self::Fixed(p) => p.publish_wire(bytes),
        }
    }

    /// Publishes an owned message; one of another topic kind is refused,
    /// naming the topic.
    pub fn publish_message(&mut self, msg: Message) -> Result<(), TransportError> {
        match (self, msg) {
            (Self::Image(p), Message::Image(m)) => p.publish_copy(m.header, &m.data),
            (Self::Tensor(p), Message::Tensor(m)) => p.publish_copy(m.header, &m.data),
            (Self::Polar(p), Message::PolarBins(m)) => p.publish_copy(m.header, &m.data),
            (Self::Costmap(p), Message::Costmap(m)) => p.publish_copy(m.header, &m.data),
            (Self::Fixed(p), m) => p.publish_message(m),
            (p, m) => Err(wrong_kind(p.topic(), &m)),
        }
    }

    fn topic(&self) -> &str {
        match self {
            Self::Image(p) => p.topic(),
            Self::Tensor(p) => p.topic(),
            Self::Polar(p) => p.topic(),
            Self::Costmap(p) => p.topic(),
            Self::Fixed(_) => "a fixed-size topic",
        }
    }

    /// Hands the last fixed-size message to subscribers that joined since
    /// (slice topics keep no history).
    pub fn deliver_history(&self) -> Result<(), TransportError> {
        match self {
            Self::Fixed(p) => p.deliver_history(),
            _ => Ok(()),
        }
    }
}
