//! Topic names of the graph, in one place.
//!
//! A topic is a readable path such as `camera/front/image`. On the vehicle it is
//! the iceoryx2 service `farsight/camera/front/image`; across machines it is the
//! zenoh key `farsight/<robot>/camera/front/image`. A [`Topic`] also carries the
//! message type, so a publisher and a subscriber of one topic cannot disagree.

use crate::msg::*;
use core::marker::PhantomData;

/// Prefix of every iceoryx2 service name and zenoh key.
pub const ROOT: &str = "farsight";

/// A typed topic: `M` is a fixed-size message, or [`Slice<H, E>`] for a header
/// plus a variable-length payload.
#[derive(Debug)]
pub struct Topic<M: ?Sized> {
    name: String,
    _m: PhantomData<fn() -> Box<M>>,
}

impl<M: ?Sized> Clone for Topic<M> {
    fn clone(&self) -> Self {
        Self {
            name: self.name.clone(),
            _m: PhantomData,
        }
    }
}

/// Marker for a topic whose messages are a header `H` plus a slice of `E`.
pub struct Slice<H, E>(PhantomData<(H, E)>);

impl<M: ?Sized> Topic<M> {
    /// A topic with a custom name (`a/b/c`: lowercase words, digits, `_`, `-`).
    pub fn new(name: impl Into<String>) -> Result<Self, TopicNameError> {
        let name = name.into();
        validate_name(&name)?;
        Ok(Self {
            name,
            _m: PhantomData,
        })
    }

    fn known(name: String) -> Self {
        debug_assert!(validate_name(&name).is_ok(), "bad built-in topic {name}");
        Self {
            name,
            _m: PhantomData,
        }
    }

    /// The readable name, e.g. `camera/front/image`.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The iceoryx2 service name on the vehicle.
    pub fn ipc_service_name(&self) -> String {
        ipc_service_name(&self.name)
    }

    /// The zenoh key for this topic on robot `robot`.
    pub fn zenoh_key(&self, robot: &str) -> String {
        zenoh_key(robot, &self.name)
    }
}

/// iceoryx2 service name of a readable topic name.
pub fn ipc_service_name(topic: &str) -> String {
    format!("{ROOT}/{topic}")
}

/// zenoh key of a readable topic name on robot `robot`.
pub fn zenoh_key(robot: &str, topic: &str) -> String {
    format!("{ROOT}/{robot}/{topic}")
}

/// Inverse of [`zenoh_key`]: `(robot, topic)`.
pub fn parse_zenoh_key(key: &str) -> Option<(&str, &str)> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix('/')?;
    let (robot, topic) = rest.split_once('/')?;
    (!robot.is_empty() && !topic.is_empty()).then_some((robot, topic))
}

/// A topic or robot name that cannot be used as an iceoryx2 service or zenoh key.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "invalid name {name:?}: {why} (use lowercase words, digits, '_' and '-', separated by '/')"
)]
pub struct TopicNameError {
    pub name: String,
    pub why: &'static str,
}

/// Checks a topic (or robot) name: non-empty `/`-separated words of
/// `[a-z0-9_-]`. zenoh reserves `*`, `$`, `?`, `#`; iceoryx2 limits length.
pub fn validate_name(name: &str) -> Result<(), TopicNameError> {
    let err = |why| {
        Err(TopicNameError {
            name: name.to_string(),
            why,
        })
    };
    if name.is_empty() {
        return err("empty");
    }
    if name.len() > 200 {
        return err("longer than 200 bytes");
    }
    for part in name.split('/') {
        if part.is_empty() {
            return err("empty path segment");
        }
        if !part
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
        {
            return err("character outside [a-z0-9_-]");
        }
    }
    Ok(())
}

pub type ImageTopic = Topic<Slice<ImageHeader, u8>>;
pub type TensorTopic = Topic<Slice<TensorHeader, f32>>;
pub type PolarBinsTopic = Topic<Slice<PolarBinsHeader, PolarCell>>;
pub type CostmapTopic = Topic<Slice<CostmapHeader, CostCell>>;

/// Raw frames of camera `camera` (e.g. `front`).
pub fn camera_image(camera: &str) -> ImageTopic {
    Topic::known(format!("camera/{camera}/image"))
}
/// Depth image of camera `camera`, registered to its frames (mono16 in the
/// source's units, or f32 metres), stamped like the frame it belongs to.
pub fn depth(camera: &str) -> ImageTopic {
    Topic::known(format!("camera/{camera}/depth"))
}
/// The camera model of camera `camera`, republished with its frames.
pub fn camera_info(camera: &str) -> Topic<CameraInfo> {
    Topic::known(format!("camera/{camera}/info"))
}
/// Per-pixel class ids (mono8) from the inference stage.
pub fn class_map(camera: &str) -> ImageTopic {
    Topic::known(format!("perception/{camera}/classes"))
}
/// Confidence of the class map (f32, probability of the chosen class).
pub fn class_confidence(camera: &str) -> ImageTopic {
    Topic::known(format!("perception/{camera}/confidence"))
}
/// Navigability image (mono8, 255 = navigable), POVNav's input.
pub fn navigability(camera: &str) -> ImageTopic {
    Topic::known(format!("perception/{camera}/navigability"))
}
/// LRN affordance heatmap (f32 in [0, 1]).
pub fn affordance_heatmap(camera: &str) -> ImageTopic {
    Topic::known(format!("perception/{camera}/heatmap"))
}
/// FITAM far-field ensemble outputs `[slices, radial bins, members, classes]`.
pub fn far_field_logits(camera: &str) -> TensorTopic {
    Topic::known(format!("perception/{camera}/far_field"))
}
/// LRN angular bins, all cameras merged.
pub fn angular_bins() -> Topic<AngularBins> {
    Topic::known("bins/angular".into())
}
/// FITAM polar cost bins in the robot frame.
pub fn polar_bins() -> PolarBinsTopic {
    Topic::known("bins/polar".into())
}
/// A costmap layer (`fused`, `local`, `far_field`, `learned`) or an external one.
pub fn costmap(layer: &str) -> CostmapTopic {
    Topic::known(format!("costmap/{layer}"))
}
/// The subgoal the servo follows.
pub fn subgoal() -> Topic<Subgoal> {
    Topic::known("nav/subgoal".into())
}
/// A named subgoal (`nav/subgoal/lrn`): one method's choice that another
/// instance follows as its goal (LRN's heading guiding POVNav or a local
/// planner), so it is not the one the servo follows.
pub fn named_subgoal(name: &str) -> Topic<Subgoal> {
    Topic::known(format!("nav/subgoal/{name}"))
}
/// The planned or visual path (frame in the message).
pub fn path(kind: &str) -> Topic<Path> {
    Topic::known(format!("nav/path/{kind}"))
}
pub fn goal() -> Topic<NavGoal> {
    Topic::known("nav/goal".into())
}
pub fn pose() -> Topic<Pose> {
    Topic::known("state/pose".into())
}
pub fn velocity_command() -> Topic<VelocityCommand> {
    Topic::known("cmd/velocity".into())
}
/// An input of the command mux: `cmd/teleop`, `cmd/autonomy`, ...
pub fn command_input(name: &str) -> Topic<VelocityCommand> {
    Topic::known(format!("cmd/{name}"))
}
pub fn estop() -> Topic<EStop> {
    Topic::known("safety/estop".into())
}
/// Health of stage `stage`.
pub fn health(stage: &str) -> Topic<StageHealth> {
    Topic::known(format!("health/{stage}"))
}

/// The message type behind a topic name, for tools that handle topics by name
/// (bridge, recorder, inspector).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TopicKind {
    Image,
    CameraInfo,
    Tensor,
    AngularBins,
    PolarBins,
    Costmap,
    Subgoal,
    Path,
    Goal,
    Pose,
    VelocityCommand,
    EStop,
    Health,
}

/// The message type of a well-known topic name, or `None`.
pub fn kind_of(topic: &str) -> Option<TopicKind> {
    let parts: Vec<&str> = topic.split('/').collect();
    Some(match parts.as_slice() {
        ["camera", _, "image" | "depth"] => TopicKind::Image,
        ["camera", _, "info"] => TopicKind::CameraInfo,
        ["perception", _, "classes" | "confidence" | "navigability" | "heatmap"] => {
            TopicKind::Image
        }
        ["perception", _, "far_field"] => TopicKind::Tensor,
        ["bins", "angular"] => TopicKind::AngularBins,
        ["bins", "polar"] => TopicKind::PolarBins,
        ["costmap", _] => TopicKind::Costmap,
        ["nav", "subgoal"] | ["nav", "subgoal", _] => TopicKind::Subgoal,
        ["nav", "path", _] => TopicKind::Path,
        ["nav", "goal"] => TopicKind::Goal,
        ["state", "pose"] => TopicKind::Pose,
        ["cmd", _] => TopicKind::VelocityCommand,
        ["safety", "estop"] => TopicKind::EStop,
        ["health", _] => TopicKind::Health,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_between_ipc_and_zenoh() {
        let t = camera_image("front");
        assert_eq!(t.name(), "camera/front/image");
        assert_eq!(t.ipc_service_name(), "farsight/camera/front/image");
        assert_eq!(t.zenoh_key("husky1"), "farsight/husky1/camera/front/image");
        assert_eq!(
            parse_zenoh_key("farsight/husky1/camera/front/image"),
            Some(("husky1", "camera/front/image"))
        );
        assert_eq!(parse_zenoh_key("other/husky1/x"), None);
    }

    #[test]
    fn every_builtin_topic_has_a_kind() {
        let names = [
            camera_image("a").name().to_string(),
            camera_info("a").name().to_string(),
            depth("a").name().to_string(),
            class_map("a").name().to_string(),
            class_confidence("a").name().to_string(),
            navigability("a").name().to_string(),
            affordance_heatmap("a").name().to_string(),
            far_field_logits("a").name().to_string(),
            angular_bins().name().to_string(),
            polar_bins().name().to_string(),
            costmap("fused").name().to_string(),
            subgoal().name().to_string(),
            named_subgoal("lrn").name().to_string(),
            path("visual").name().to_string(),
            goal().name().to_string(),
            pose().name().to_string(),
            velocity_command().name().to_string(),
            estop().name().to_string(),
            health("bridge").name().to_string(),
        ];
        for n in names {
            assert!(kind_of(&n).is_some(), "{n} has no kind");
            validate_name(&n).unwrap();
        }
        assert_eq!(kind_of("camera/front/nonsense"), None);
        assert_eq!(kind_of("nav/subgoal/lrn"), Some(TopicKind::Subgoal));
        assert_eq!(kind_of("nav/subgoal/lrn/x"), None);
    }

    #[test]
    fn bad_names_are_refused_with_reason() {
        let e = Topic::<Pose>::new("Camera/*").unwrap_err();
        assert_eq!(e.why, "character outside [a-z0-9_-]");
        assert!(Topic::<Pose>::new("a//b").is_err());
        assert!(Topic::<Pose>::new("").is_err());
    }
}
