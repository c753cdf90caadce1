//! Owned messages of any farsight topic: what a stage's step takes in and
//! gives out (`farsight_stage::runtime`), with no transport type in sight.
//! The process runtime copies them out of and into iceoryx2's shared memory;
//! the in-process executor hands them from one stage to the next as they
//! are. A topic's name fixes its [`TopicKind`] and so its variant here.

use crate::msg::*;
use crate::topics::TopicKind;
use crate::transport::Stamped;

/// A header and its elements (an image's pixels, a costmap's cells).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sliced<H, E> {
    pub header: H,
    pub data: Vec<E>,
}

pub type Image = Sliced<ImageHeader, u8>;
pub type Tensor = Sliced<TensorHeader, f32>;
pub type PolarBins = Sliced<PolarBinsHeader, PolarCell>;
pub type Costmap = Sliced<CostmapHeader, CostCell>;

macro_rules! messages {
    ($($variant:ident($ty:ty)),+ $(,)?) => {
        /// One message of any topic, owned.
        // The fixed-size variants (a path of 512 points, 4 KiB, is the largest) are
        // moved by value: boxing them would allocate for every pose and
        // command, the messages a graph moves most often.
        #[allow(clippy::large_enum_variant)]
        #[derive(Debug, Clone, PartialEq)]
        pub enum Message {
            $($variant($ty),)+
        }

        impl Message {
            /// The kind of topic this message travels on.
            pub fn kind(&self) -> TopicKind {
                match self {
                    $(Self::$variant(_) => TopicKind::$variant,)+
                }
            }
        }

        $(
            impl From<$ty> for Message {
                fn from(m: $ty) -> Self {
                    Self::$variant(m)
                }
            }

            impl TryFrom<Message> for $ty {
                type Error = Message;
                fn try_from(m: Message) -> Result<Self, Message> {
                    match m {
                        Message::$variant(m) => Ok(m),
                        other => Err(other),
                    }
                }
            }
        )+
    };
}

messages!(
    Image(Image),
    CameraInfo(CameraInfo),
    Tensor(Tensor),
    AngularBins(AngularBins),
    PolarBins(PolarBins),
    Costmap(Costmap),
    Subgoal(Subgoal),
    Path(Path),
    Goal(NavGoal),
    Pose(Pose),
    VelocityCommand(VelocityCommand),
    EStop(EStop),
    Health(StageHealth),
);

impl Message {
    /// The capture stamp the message carries.
    pub fn stamp(&self) -> Stamp {
        match self {
            Self::Image(m) => m.header.stamp(),
            Self::Tensor(m) => m.header.stamp(),
            Self::PolarBins(m) => m.header.stamp(),
            Self::Costmap(m) => m.header.stamp(),
            Self::CameraInfo(m) => m.stamp(),
            Self::AngularBins(m) => m.stamp(),
            Self::Subgoal(m) => m.stamp(),
            Self::Path(m) => m.stamp(),
            Self::Goal(m) => m.stamp(),
            Self::Pose(m) => m.stamp(),
            Self::VelocityCommand(m) => m.stamp(),
            Self::EStop(m) => m.stamp(),
            Self::Health(m) => m.stamp(),
        }
    }
}

impl Message {
    /// Decodes a message of topic kind `kind` from its wire encoding (what
    /// the bridge sends over zenoh and recordings store).
    pub fn from_wire(
        kind: TopicKind,
        bytes: &[u8],
    ) -> Result<Self, crate::transport::wire::WireError> {
        use crate::transport::wire::{decode_message, decode_slice};
        fn sliced<H: serde::de::DeserializeOwned, E: bytemuck::Pod>(
            bytes: &[u8],
        ) -> Result<Sliced<H, E>, crate::transport::wire::WireError> {
            decode_slice(bytes).map(|(header, data)| Sliced { header, data })
        }
        Ok(match kind {
            TopicKind::Image => Self::Image(sliced(bytes)?),
            TopicKind::Tensor => Self::Tensor(sliced(bytes)?),
            TopicKind::PolarBins => Self::PolarBins(sliced(bytes)?),
            TopicKind::Costmap => Self::Costmap(sliced(bytes)?),
            TopicKind::CameraInfo => Self::CameraInfo(decode_message(bytes)?),
            TopicKind::AngularBins => Self::AngularBins(decode_message(bytes)?),
            TopicKind::Subgoal => Self::Subgoal(decode_message(bytes)?),
            TopicKind::Path => Self::Path(decode_message(bytes)?),
            TopicKind::Goal => Self::Goal(decode_message(bytes)?),
            TopicKind::Pose => Self::Pose(decode_message(bytes)?),
            TopicKind::VelocityCommand => Self::VelocityCommand(decode_message(bytes)?),
            TopicKind::EStop => Self::EStop(decode_message(bytes)?),
            TopicKind::Health => Self::Health(decode_message(bytes)?),
        })
    }
}

impl Message {
    /// The message in the wire encoding the bridge sends and recordings
    /// store ([`crate::transport::wire`]).
    pub fn to_wire(&self) -> Result<Vec<u8>, crate::transport::wire::WireError> {
        use crate::transport::wire::{encode_message, encode_slice};
        match self {
            Self::Image(m) => encode_slice(&m.header, &m.data),
            Self::Tensor(m) => encode_slice(&m.header, &m.data),
            Self::PolarBins(m) => encode_slice(&m.header, &m.data),
            Self::Costmap(m) => encode_slice(&m.header, &m.data),
            Self::CameraInfo(m) => encode_message(m),
            Self::AngularBins(m) => encode_message(m),
            Self::Subgoal(m) => encode_message(m),
            Self::Path(m) => encode_message(m),
            Self::Goal(m) => encode_message(m),
            Self::Pose(m) => encode_message(m),
            Self::VelocityCommand(m) => encode_message(m),
            Self::EStop(m) => encode_message(m),
            Self::Health(m) => encode_message(m),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_comes_back_from_its_wire_bytes_as_the_kind_asked_for() {
        let pose = Pose {
            stamp: Stamp::new(3, 9),
            yaw_rad: 0.5,
            ..Default::default()
        };
        let bytes = Message::from(pose).to_wire().unwrap();
        assert_eq!(
            Message::from_wire(TopicKind::Pose, &bytes).unwrap(),
            Message::Pose(pose)
        );
        let costmap = Costmap {
            header: CostmapHeader {
                width: 2,
                height: 1,
                ..Default::default()
            },
            data: vec![CostCell::default(); 2],
        };
        let bytes = Message::from(costmap.clone()).to_wire().unwrap();
        assert_eq!(
            Message::from_wire(TopicKind::Costmap, &bytes).unwrap(),
            Message::Costmap(costmap)
        );
        assert!(
            Message::from_wire(TopicKind::Costmap, &Message::Pose(pose).to_wire().unwrap())
                .is_err(),
            "a pose's bytes are not a costmap"
        );
    }

    #[test]
    fn a_message_converts_back_only_to_its_own_type() {
        let pose = Pose {
            stamp: Stamp {
                frame_seq: 7,
                ..Default::default()
            },
            ..Default::default()
        };
        let m = Message::from(pose);
        assert_eq!(m.kind(), TopicKind::Pose);
        assert_eq!(m.stamp().frame_seq, 7);
        let back: Result<NavGoal, Message> = m.clone().try_into();
        assert_eq!(back, Err(m.clone()), "a pose is not a goal");
        assert_eq!(Pose::try_from(m), Ok(pose));
        let image = Message::from(Image {
            header: ImageHeader::default(),
            data: vec![1, 2, 3],
        });
        assert_eq!(image.kind(), TopicKind::Image);
    }
}
