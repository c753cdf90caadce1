//! Message types for every edge of the farsight graph.
//!
//! Each type is `#[repr(C)]` + [`ZeroCopySend`] so it can live in iceoryx2 shared
//! memory, and serde-serialisable so the same value crosses machines over zenoh
//! (postcard). Every message carries a [`Stamp`]: the sequence number and capture
//! time of the camera frame it was derived from, so end-to-end latency can be read
//! off any message in the graph.
//!
//! Variable-size data (pixels, tensors, grids) travels as a typed header plus a
//! slice: [`ImageHeader`] + `[u8]`, [`TensorHeader`] + `[f32]`,
//! [`PolarBinsHeader`] + `[PolarCell]`, [`CostmapHeader`] + `[CostCell]`.
//!
//! Enum-like fields are `repr(transparent)` codes rather than Rust enums: a peer
//! may write any bits into shared memory and an out-of-range Rust enum would be
//! undefined behaviour, while an unknown code is just a value to reject.

use crate::fixed::{FixedStr, FixedVec};
use bytemuck::{Pod, Zeroable};
use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

/// Declares a `u32` code type with named constants, readable `Debug`/serde.
macro_rules! code_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $konst:ident = $val:expr => $text:expr),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
        #[repr(transparent)]
        pub struct $name(pub u32);

        // SAFETY: a transparent u32, valid for every bit pattern.
        unsafe impl ZeroCopySend for $name {}

        impl $name {
            $($(#[$vm])* pub const $konst: Self = Self($val);)+
            /// All known codes.
            pub const ALL: &'static [Self] = &[$(Self::$konst),+];

            /// The readable name, or `None` for a code this build does not know.
            pub fn name(self) -> Option<&'static str> {
                match self.0 { $($val => Some($text),)+ _ => None }
            }

            /// Parses a readable name (as written in configs and by `echo`).
            pub fn from_name(s: &str) -> Option<Self> {
                match s { $($text => Some(Self::$konst),)+ _ => None }
            }

            pub fn is_known(self) -> bool {
                self.name().is_some()
            }
        }

        impl core::fmt::Debug for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                match self.name() {
                    Some(n) => f.write_str(n),
                    None => write!(f, "unknown({})", self.0),
                }
            }
        }

        impl core::fmt::Display for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                core::fmt::Debug::fmt(self, f)
            }
        }

        impl Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_u32(self.0)
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                u32::deserialize(d).map(Self)
            }
        }
    };
}

/// Where a message came from in time: the camera frame it was derived from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::Stamp")]
pub struct Stamp {
    /// Sequence number of the source frame (or of this message, for sources
    /// that are not derived from a frame, such as pose).
    pub frame_seq: u64,
    /// Capture time of the source frame, nanoseconds on the graph clock
    /// (Unix epoch on the robot, the recording's clock in a replay).
    pub capture_time_ns: u64,
}

impl Stamp {
    pub fn new(frame_seq: u64, capture_time_ns: u64) -> Self {
        Self {
            frame_seq,
            capture_time_ns,
        }
    }

    /// Age of the source frame at `now_ns`, in seconds (0 if `now_ns` is earlier).
    pub fn age_s(&self, now_ns: u64) -> f64 {
        now_ns.saturating_sub(self.capture_time_ns) as f64 * 1e-9
    }
}

code_enum! {
    /// Layout of the bytes of an image payload.
    PixelEncoding {
        RGB8 = 0 => "rgb8",
        BGR8 = 1 => "bgr8",
        RGBA8 = 2 => "rgba8",
        MONO8 = 3 => "mono8",
        MONO16 = 4 => "mono16",
        /// One little-endian f32 per pixel (heatmaps, confidences, depth in metres).
        F32 = 5 => "f32",
        /// YUV 4:2:2, as V4L2 cameras deliver it.
        YUYV = 6 => "yuyv",
        /// A compressed image: width/height describe the decoded image, stride is 0.
        JPEG = 7 => "jpeg",
        PNG = 8 => "png",
    }
}

impl PixelEncoding {
    /// Bytes per pixel for raw encodings, `None` for compressed or unknown ones.
    pub fn bytes_per_pixel(self) -> Option<usize> {
        match self {
            Self::RGB8 | Self::BGR8 => Some(3),
            Self::RGBA8 | Self::F32 => Some(4),
            Self::MONO8 => Some(1),
            Self::MONO16 | Self::YUYV => Some(2),
            _ => None,
        }
    }

    pub fn is_compressed(self) -> bool {
        matches!(self, Self::JPEG | Self::PNG)
    }
}

/// Header of an image payload (camera frame, class-id map, mask, heatmap).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::ImageHeader")]
pub struct ImageHeader {
    pub stamp: Stamp,
    pub camera_id: u32,
    pub width: u32,
    pub height: u32,
    /// Bytes from the start of one row to the next (0 for compressed payloads).
    pub stride_bytes: u32,
    pub encoding: PixelEncoding,
}

/// Why an image payload does not match its header.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ImageLayoutError {
    #[error("unknown pixel encoding {0}")]
    UnknownEncoding(u32),
    #[error(
        "stride {stride} bytes is shorter than a {width}-pixel row of {encoding} ({row} bytes)"
    )]
    StrideTooShort {
        stride: u32,
        width: u32,
        encoding: PixelEncoding,
        row: usize,
    },
    #[error("payload holds {got} bytes but {width}x{height} at stride {stride} needs {need}")]
    WrongSize {
        got: usize,
        need: usize,
        width: u32,
        height: u32,
        stride: u32,
    },
}

impl ImageHeader {
    /// A tightly packed raw image header.
    pub fn packed(
        stamp: Stamp,
        camera_id: u32,
        width: u32,
        height: u32,
        encoding: PixelEncoding,
    ) -> Self {
        let bpp = encoding.bytes_per_pixel().unwrap_or(0) as u32;
        Self {
            stamp,
            camera_id,
            width,
            height,
            stride_bytes: width * bpp,
            encoding,
        }
    }

    /// Bytes a raw payload must hold (`None` for compressed encodings).
    pub fn raw_len(&self) -> Option<usize> {
        self.encoding.bytes_per_pixel()?;
        Some(self.stride_bytes as usize * self.height as usize)
    }

    /// Checks that `payload_len` bytes fit this header. Every consumer calls this
    /// before reading pixels: a corrupt or mismatched frame is an error, not a panic.
    pub fn validate(&self, payload_len: usize) -> Result<(), ImageLayoutError> {
        if !self.encoding.is_known() {
            return Err(ImageLayoutError::UnknownEncoding(self.encoding.0));
        }
        let Some(bpp) = self.encoding.bytes_per_pixel() else {
            return Ok(());
        };
        let row = self.width as usize * bpp;
        if (self.stride_bytes as usize) < row {
            return Err(ImageLayoutError::StrideTooShort {
                stride: self.stride_bytes,
                width: self.width,
                encoding: self.encoding,
                row,
            });
        }
        let need = self.stride_bytes as usize * self.height as usize;
        if payload_len != need {
            return Err(ImageLayoutError::WrongSize {
                got: payload_len,
                need,
                width: self.width,
                height: self.height,
                stride: self.stride_bytes,
            });
        }
        Ok(())
    }
}

/// Header of a dense f32 tensor (model outputs that are not images), row-major.
///
/// FITAM far-field outputs use `dims = [slices, radial_bins, members, classes]`.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::TensorHeader")]
pub struct TensorHeader {
    pub stamp: Stamp,
    pub camera_id: u32,
    /// Number of used entries in `dims`.
    pub rank: u32,
    pub dims: [u32; 4],
}

impl TensorHeader {
    pub fn new(stamp: Stamp, camera_id: u32, dims: &[u32]) -> Self {
        let mut d = [1u32; 4];
        let rank = dims.len().min(4);
        d[..rank].copy_from_slice(&dims[..rank]);
        Self {
            stamp,
            camera_id,
            rank: rank as u32,
            dims: d,
        }
    }

    pub fn shape(&self) -> &[u32] {
        &self.dims[..(self.rank as usize).min(4)]
    }

    /// Elements the shape holds; `usize::MAX` when that overflows (a
    /// corrupt header from the wire: no payload is that long).
    pub fn element_count(&self) -> usize {
        self.shape()
            .iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d as usize))
            .unwrap_or(usize::MAX)
    }
}

/// Maximum number of LRN angular bins (1 degree bins all round).
pub const MAX_ANGULAR_BINS: usize = 360;

/// LRN angular bin scores around the robot (section III-B).
///
/// Bin `i` covers headings `[first_bin_start_rad + i*bin_width_rad, +bin_width_rad)`,
/// counter-clockwise in the robot frame (0 = straight ahead, +pi/2 = left).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::AngularBins")]
pub struct AngularBins {
    pub stamp: Stamp,
    pub first_bin_start_rad: f32,
    pub bin_width_rad: f32,
    /// Normalised, EMA-filtered affordance per bin.
    pub scores: FixedVec<f32, MAX_ANGULAR_BINS>,
    /// 1 where at least one camera sees the bin. An unobserved bin is unknown, not zero.
    pub observed: FixedVec<u8, MAX_ANGULAR_BINS>,
}

/// One FITAM polar bin (heading x range) in the robot frame.
#[derive(
    Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize,
)]
#[repr(C)]
#[type_name("farsight::PolarCell")]
pub struct PolarCell {
    /// Most likely class's cost (1 / class speed).
    pub cost_s_per_m: f32,
    /// Measurement variance R for the Kalman update.
    pub variance: f32,
    /// Most likely class index.
    pub class_id: u32,
    /// Its probability (mean of the ensemble members' softmax).
    pub probability: f32,
}

impl PolarCell {
    /// A bin that carries no measurement: no cost, infinite variance, no
    /// class. The Kalman update skips it.
    pub const NO_MEASUREMENT: PolarCell = PolarCell {
        cost_s_per_m: f32::NAN,
        variance: f32::INFINITY,
        class_id: u32::MAX,
        probability: 0.0,
    };
}

/// Maximum radial bin edges of a polar bin message.
pub const MAX_RANGE_EDGES: usize = 16;

/// Header of FITAM polar cost bins; payload is `heading_bins * (edges-1)` cells,
/// heading-major.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::PolarBinsHeader")]
pub struct PolarBinsHeader {
    pub stamp: Stamp,
    pub heading_bins: u32,
    /// Heading of the start of bin 0, robot frame, counter-clockwise.
    pub first_heading_start_rad: f32,
    pub heading_width_rad: f32,
    pub range_edges_m: FixedVec<f32, MAX_RANGE_EDGES>,
}

/// One cell of a costmap.
#[derive(
    Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize,
)]
#[repr(C)]
#[type_name("farsight::CostCell")]
pub struct CostCell {
    /// Traversal cost in seconds per metre; `f32::INFINITY` is lethal.
    pub cost_s_per_m: f32,
    /// Variance of the cost estimate (0 = observed by near-field sensing).
    pub variance: f32,
}

code_enum! {
    /// Which layer of the fused map a costmap message holds.
    CostmapLayer {
        FUSED = 0 => "fused",
        LOCAL = 1 => "local",
        FAR_FIELD = 2 => "far_field",
        LEARNED = 3 => "learned",
    }
}

/// Header of a costmap in the local ENU world frame; payload is `width*height`
/// cells, row-major with row 0 at the north edge (FITAM's convention).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::CostmapHeader")]
pub struct CostmapHeader {
    pub stamp: Stamp,
    pub layer: CostmapLayer,
    pub width: u32,
    pub height: u32,
    pub resolution_m: f32,
    /// World x of the centre of column 0.
    pub x_min_m: f64,
    /// World y of the centre of row 0 (the northmost row).
    pub y_max_m: f64,
}

code_enum! {
    /// Which method produced a subgoal.
    SubgoalSource {
        LRN = 0 => "lrn",
        POVNAV = 1 => "povnav",
        DSTAR_LITE = 2 => "dstar_lite",
        HIP = 3 => "hip",
        GOAL_HEURISTIC = 4 => "goal_heuristic",
    }
}

code_enum! {
    /// POVNav's operating mode (section 4.7).
    ServoMode {
        SAFE = 0 => "safe",
        FALLBACK = 1 => "fallback",
        /// Nothing navigable: the robot must not move forward.
        BLOCKED = 2 => "blocked",
    }
}

/// A subgoal for the servo stage, with the features that explain it.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::Subgoal")]
pub struct Subgoal {
    pub stamp: Stamp,
    pub source: SubgoalSource,
    pub mode: ServoMode,
    /// Heading of the subgoal in the robot frame (0 ahead, counter-clockwise).
    pub heading_rad: f32,
    /// Subgoal position in the robot frame.
    pub x_m: f32,
    pub y_m: f32,
    /// Subgoal in image pixels (NaN when it did not come from an image).
    pub image_u_px: f32,
    pub image_v_px: f32,
    /// POVNav proximity feature lambda (pixels) and alignment phi (radians);
    /// NaN for methods without them.
    pub proximity_lambda_px: f32,
    pub alignment_phi_rad: f32,
}

code_enum! {
    /// Coordinate frame of a path.
    PathFrame {
        ROBOT = 0 => "robot",
        WORLD = 1 => "world",
        IMAGE = 2 => "image",
    }
}

/// Maximum points in a [`Path`] message.
pub const MAX_PATH_POINTS: usize = 512;

/// A path: metres in the robot or world frame, or pixels in the image.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::Path")]
pub struct Path {
    pub stamp: Stamp,
    pub frame: PathFrame,
    pub camera_id: u32,
    pub points: FixedVec<[f32; 2], MAX_PATH_POINTS>,
}

code_enum! {
    /// Why the servo stage commanded what it did.
    CommandReason {
        TRACKING = 0 => "tracking",
        STALE_INPUT = 1 => "stale_input",
        ESTOP = 2 => "estop",
        GOAL_REACHED = 3 => "goal_reached",
        NO_SUBGOAL = 4 => "no_subgoal",
        TELEOP = 5 => "teleop",
    }
}

/// A velocity command for the platform.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
// v2: `ttl_ms` added; the name keeps an old process from reading the new
// layout (same size, the old padding) as its own.
#[type_name("farsight::VelocityCommand.v2")]
pub struct VelocityCommand {
    pub stamp: Stamp,
    pub linear_mps: f32,
    pub angular_radps: f32,
    pub reason: CommandReason,
    /// How long a base may obey this command after it *received* it, in
    /// milliseconds (then it stops unless a newer command has come): counted
    /// on the base's own clock, since that is not synchronised with the
    /// graph's. 0: the base's own cap. See [`crate::base`].
    pub ttl_ms: u16,
}

impl VelocityCommand {
    pub fn stop(stamp: Stamp, reason: CommandReason) -> Self {
        Self {
            stamp,
            linear_mps: 0.0,
            angular_radps: 0.0,
            reason,
            ttl_ms: 0,
        }
    }
}

/// A GNSS fix.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::GpsFix")]
pub struct GpsFix {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub altitude_m: f64,
    /// 1 when the fix is valid.
    pub valid: u8,
}

/// The robot's pose in the local ENU frame, with its GPS fix.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::Pose")]
pub struct Pose {
    pub stamp: Stamp,
    /// East, north, up, metres, in the local ENU frame.
    pub position_m: [f64; 3],
    /// Heading, counter-clockwise from east.
    pub yaw_rad: f64,
    /// Covariance of (x, y, yaw), row-major 3x3.
    pub covariance: [f64; 9],
    pub linear_mps: f32,
    pub angular_radps: f32,
    pub gps: GpsFix,
}

impl CostmapHeader {
    /// World (ENU) centre of payload cell `k` (row-major, row 0 north).
    pub fn cell_centre_m(&self, k: usize) -> [f64; 2] {
        let w = (self.width as usize).max(1);
        let res = self.resolution_m as f64;
        [
            self.x_min_m + (k % w) as f64 * res,
            self.y_max_m - (k / w) as f64 * res,
        ]
    }

    /// Payload index of the cell holding world point (x, y), FITAM's rule
    /// `j = floor((x - x_min) / res + 0.5)`, `i = floor((y_max - y) / res + 0.5)`;
    /// `None` outside the map.
    pub fn cell_index(&self, x_m: f64, y_m: f64) -> Option<usize> {
        let res = self.resolution_m as f64;
        let j = ((x_m - self.x_min_m) / res + 0.5).floor();
        let i = ((self.y_max_m - y_m) / res + 0.5).floor();
        (j >= 0.0 && i >= 0.0 && j < self.width as f64 && i < self.height as f64)
            .then(|| i as usize * self.width as usize + j as usize)
    }

    /// Checks the header against its payload: the cell count, a positive
    /// finite resolution and a finite origin. The error names what is wrong.
    pub fn validate(&self, cells: usize) -> Result<(), String> {
        if self.cell_count() != cells {
            return Err(format!(
                "costmap header says {}x{} cells but the payload holds {cells}",
                self.width, self.height
            ));
        }
        if !(self.resolution_m.is_finite() && self.resolution_m > 0.0) {
            return Err(format!(
                "costmap resolution {} m is not a positive size",
                self.resolution_m
            ));
        }
        if !(self.x_min_m.is_finite() && self.y_max_m.is_finite()) {
            return Err(format!(
                "costmap origin ({}, {}) is not finite",
                self.x_min_m, self.y_max_m
            ));
        }
        Ok(())
    }

    /// Cells the payload must hold.
    pub fn cell_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

impl Pose {
    /// A world (ENU) point in this pose's robot frame (x ahead, y left).
    pub fn to_robot_frame(&self, world_m: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.yaw_rad.sin_cos();
        let (dx, dy) = (
            world_m[0] - self.position_m[0],
            world_m[1] - self.position_m[1],
        );
        [c * dx + s * dy, -s * dx + c * dy]
    }

    /// A robot-frame point in the world (ENU) frame.
    pub fn to_world_frame(&self, robot_m: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.yaw_rad.sin_cos();
        [
            self.position_m[0] + c * robot_m[0] - s * robot_m[1],
            self.position_m[1] + s * robot_m[0] + c * robot_m[1],
        ]
    }
}

code_enum! {
    /// How a navigation goal is given.
    GoalKind {
        /// `latitude_deg`/`longitude_deg`, converted to the local ENU frame.
        GPS = 0 => "gps",
        /// `x_m`/`y_m` in the local ENU frame.
        LOCAL = 1 => "local",
    }
}

/// Where to go.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::NavGoal")]
pub struct NavGoal {
    pub stamp: Stamp,
    pub kind: GoalKind,
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub x_m: f64,
    pub y_m: f64,
    /// Distance at which the goal counts as reached.
    pub tolerance_m: f32,
}

/// Emergency stop. While `active` is 1 ([`EStop::PRESSED`]) the servo
/// publishes zero velocity; the command mux latches it until an operator
/// sends [`EStop::CLEAR`]. An operator's e-stop tool sends its state
/// periodically: the mux's deadman takes that as the operator link's heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::EStop")]
pub struct EStop {
    pub stamp: Stamp,
    pub active: u8,
    pub source: FixedStr<32>,
}

impl EStop {
    /// The button is not pressed (a heartbeat; does not clear a latch).
    pub const RELEASED: u8 = 0;
    /// Stop now; the mux latches it.
    pub const PRESSED: u8 = 1;
    /// An operator clears the mux's latched e-stop.
    pub const CLEAR: u8 = 2;
}

code_enum! {
    /// Coarse state of a stage.
    HealthState {
        STARTING = 0 => "starting",
        OK = 1 => "ok",
        /// Running but not producing normal output (stale inputs, drops).
        DEGRADED = 2 => "degraded",
        ERROR = 3 => "error",
        STOPPING = 4 => "stopping",
    }
}

/// What a stage says about itself, at a fixed rate.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::StageHealth")]
pub struct StageHealth {
    /// `frame_seq` of the last frame processed; `capture_time_ns` = time of the report.
    pub stamp: Stamp,
    pub stage: FixedStr<32>,
    pub state: HealthState,
    pub pid: u32,
    pub messages_in: u64,
    pub messages_out: u64,
    /// Inputs dropped as invalid (corrupt frame, NaN output, ...).
    pub dropped: u64,
    /// Inputs skipped by latest-value semantics because a newer one was waiting.
    pub skipped: u64,
    /// Age of the last processed frame when its output was published.
    pub last_latency_ms: f32,
    pub reason: FixedStr<128>,
}

code_enum! {
    /// Lens model of a camera.
    LensModel {
        /// Pinhole with plumb-bob (Brown-Conrady k1 k2 p1 p2 k3) distortion.
        PINHOLE = 0 => "pinhole",
        /// Equidistant fisheye (Kannala-Brandt k1..k4).
        FISHEYE = 1 => "fisheye",
    }
}

/// The camera model that goes with a camera's frames (see [`crate::camera`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[repr(C)]
#[type_name("farsight::CameraInfo")]
pub struct CameraInfo {
    pub stamp: Stamp,
    pub camera_id: u32,
    pub name: FixedStr<32>,
    pub width: u32,
    pub height: u32,
    pub lens: LensModel,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// plumb_bob: k1 k2 p1 p2 k3; fisheye: k1 k2 k3 k4 (rest 0).
    pub distortion: [f64; 5],
    /// Rotation camera-optical -> robot as a unit quaternion (x, y, z, w).
    pub mount_rotation_xyzw: [f64; 4],
    /// Camera centre in the robot frame (x forward, y left, z up), metres.
    pub mount_translation_m: [f64; 3],
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn costmap_cells_by_the_reference_rule() {
        let h = CostmapHeader {
            width: 4,
            height: 3,
            resolution_m: 2.0,
            x_min_m: 10.0,
            y_max_m: 20.0,
            ..Default::default()
        };
        // Column j spans x in [10 + 2j - 1, 10 + 2j + 1); row i spans y down from 20.
        assert_eq!(h.cell_index(10.0, 20.0), Some(0));
        assert_eq!(h.cell_index(10.99, 19.01), Some(0));
        assert_eq!(
            h.cell_index(11.0, 20.0),
            Some(1),
            "the boundary goes to the next cell"
        );
        assert_eq!(h.cell_index(16.0, 16.0), Some(2 * 4 + 3));
        assert_eq!(h.cell_index(8.9, 20.0), None);
        assert_eq!(
            h.cell_index(10.0, 21.0),
            Some(0),
            "row 0 spans y in (19, 21]"
        );
        assert_eq!(h.cell_index(10.0, 21.5), None);
        for k in 0..12 {
            let [x, y] = h.cell_centre_m(k);
            assert_eq!(h.cell_index(x, y), Some(k));
        }
    }

    #[test]
    fn costmap_headers_are_checked_against_their_payload() {
        let h = CostmapHeader {
            width: 4,
            height: 3,
            resolution_m: 1.0,
            ..Default::default()
        };
        assert!(h.validate(12).is_ok());
        assert!(h
            .validate(11)
            .unwrap_err()
            .contains("4x3 cells but the payload holds 11"));
        let bad = CostmapHeader {
            resolution_m: 0.0,
            ..h
        };
        assert!(bad.validate(12).unwrap_err().contains("resolution 0"));
        let bad = CostmapHeader {
            x_min_m: f64::NAN,
            ..h
        };
        assert!(bad.validate(12).unwrap_err().contains("not finite"));
    }

    #[test]
    fn pose_frame_transforms_by_hand() {
        // Robot at (10, 5) facing north (yaw 90 deg): a point 2 m north of it
        // is 2 m ahead; a point 1 m east is 1 m to its right.
        let pose = Pose {
            position_m: [10.0, 5.0, 0.0],
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..Default::default()
        };
        let near =
            |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12;
        assert!(near(pose.to_robot_frame([10.0, 7.0]), [2.0, 0.0]));
        assert!(near(pose.to_robot_frame([11.0, 5.0]), [0.0, -1.0]));
        assert!(near(pose.to_world_frame([0.0, -1.0]), [11.0, 5.0]));
        assert!(near(
            pose.to_world_frame(pose.to_robot_frame([-3.0, 8.5])),
            [-3.0, 8.5]
        ));
    }

    #[test]
    fn image_header_validate_names_the_mismatch() {
        let h = ImageHeader::packed(Stamp::new(1, 2), 0, 4, 3, PixelEncoding::RGB8);
        assert_eq!(h.raw_len(), Some(36));
        assert!(h.validate(36).is_ok());
        let err = h.validate(35).unwrap_err();
        assert_eq!(
            err.to_string(),
            "payload holds 35 bytes but 4x3 at stride 12 needs 36"
        );
        let mut bad = h;
        bad.stride_bytes = 11;
        assert!(matches!(
            bad.validate(33),
            Err(ImageLayoutError::StrideTooShort { .. })
        ));
        bad.encoding = PixelEncoding(77);
        assert_eq!(bad.validate(0), Err(ImageLayoutError::UnknownEncoding(77)));
    }

    #[test]
    fn codes_print_names_and_flag_unknown_values() {
        assert_eq!(format!("{:?}", PixelEncoding::YUYV), "yuyv");
        assert_eq!(format!("{:?}", PixelEncoding(1234)), "unknown(1234)");
        assert_eq!(
            CommandReason::from_name("estop"),
            Some(CommandReason::ESTOP)
        );
        assert!(!HealthState(99).is_known());
    }

    #[test]
    fn tensor_header_shape() {
        let t = TensorHeader::new(Stamp::default(), 0, &[32, 3, 15, 3]);
        assert_eq!(t.shape(), &[32, 3, 15, 3]);
        assert_eq!(t.element_count(), 32 * 3 * 15 * 3);
    }

    /// Found by fuzzing (tools/fuzz): four u32::MAX dims overflowed the
    /// product (a panic with overflow checks on) in bin-projection's check
    /// of a received tensor.
    #[test]
    fn tensor_element_count_of_a_huge_shape_saturates() {
        let t = TensorHeader::new(Stamp::default(), 0, &[u32::MAX; 4]);
        assert_eq!(t.element_count(), usize::MAX);
        let t = TensorHeader::new(Stamp::default(), 0, &[u32::MAX, 0, u32::MAX, u32::MAX]);
        assert_eq!(t.element_count(), 0);
    }

    #[test]
    fn stamp_age_never_negative() {
        let s = Stamp::new(0, 2_000_000_000);
        assert_eq!(s.age_s(1_000_000_000), 0.0);
        assert!((s.age_s(2_500_000_000) - 0.5).abs() < 1e-12);
    }
}
