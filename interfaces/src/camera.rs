//! Camera models: pixel <-> bearing for pinhole cameras with plumb-bob
//! distortion and for equidistant (Kannala-Brandt) fisheye lenses, and the
//! camera mount on the robot.
//!
//! LRN (section III-B) assigns every heatmap pixel to an angular bin by its
//! bearing in the robot frame, for fisheye and rear cameras too; POVNav needs
//! the focal length and camera height for its safe path width. Both start here.
//!
//! Frames: the camera *optical* frame has z forward, x right, y down (OpenCV,
//! ROS `camera_info`). The robot frame is REP-103: x forward, y left, z up.
//!
//! ```
//! use farsight_interfaces::camera::{Camera, CameraModel, Lens, Mount};
//!
//! let model = CameraModel::pinhole(640, 360, 400.0, 400.0, 320.0, 180.0);
//! // A rear camera: yawed 180 degrees.
//! let rear = Camera::new(1, "rear", model, Mount::from_xyz_rpy_deg([-0.5, 0.0, 1.0], [0.0, 0.0, 180.0]));
//! // The image centre looks straight backwards.
//! let bearing = rear.pixel_bearing_rad(320.0, 180.0).unwrap();
//! assert!((bearing.abs() - std::f64::consts::PI).abs() < 1e-9);
//! ```

use crate::fixed::FixedStr;
use crate::msg::{CameraInfo, LensModel, Stamp};
use nalgebra::{Matrix3, Point2, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Lens distortion model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lens {
    /// Brown-Conrady "plumb_bob": radial k1 k2 k3, tangential p1 p2.
    PlumbBob {
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    },
    /// Equidistant fisheye: theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8).
    KannalaBrandt { k1: f64, k2: f64, k3: f64, k4: f64 },
}

/// Intrinsics and lens of one camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub lens: Lens,
}

impl CameraModel {
    /// An undistorted pinhole camera.
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            lens: Lens::PlumbBob {
                k1: 0.0,
                k2: 0.0,
                p1: 0.0,
                p2: 0.0,
                k3: 0.0,
            },
        }
    }

    /// The same camera for an image resized to `width` x `height` (the
    /// inference stage's model input, for example).
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            // Pixel centres: the continuous coordinate of pixel i's centre is i + 0.5.
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
            lens: self.lens,
        }
    }

    /// Projects a point in the optical frame to pixel coordinates; `None` if it
    /// is behind a pinhole camera or outside the fisheye's model.
    pub fn project(&self, p: &Vector3<f64>) -> Option<Point2<f64>> {
        let (xd, yd) = match self.lens {
            Lens::PlumbBob { k1, k2, p1, p2, k3 } => {
                if p.z <= 1e-12 {
                    return None;
                }
                let (x, y) = (p.x / p.z, p.y / p.z);
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                (
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Lens::KannalaBrandt { k1, k2, k3, k4 } => {
                let r = (p.x * p.x + p.y * p.y).sqrt();
                if r < 1e-12 {
                    if p.z <= 0.0 {
                        return None;
                    }
                    (0.0, 0.0)
                } else {
                    let theta = r.atan2(p.z);
                    let t2 = theta * theta;
                    let theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
                    (theta_d * p.x / r, theta_d * p.y / r)
                }
            }
        };
        Some(Point2::new(self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// The unit ray in the optical frame through pixel (`u`, `v`).
    pub fn unproject(&self, u: f64, v: f64) -> Vector3<f64> {
        let xd = (u - self.cx) / self.fx;
        let yd = (v - self.cy) / self.fy;
        match self.lens {
            Lens::PlumbBob { k1, k2, p1, p2, k3 } => {
                // Fixed-point inversion of the distortion (as OpenCV's undistortPoints).
                let (mut x, mut y) = (xd, yd);
                for _ in 0..20 {
                    let r2 = x * x + y * y;
                    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                    let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
                    let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
                    x = (xd - dx) / radial;
                    y = (yd - dy) / radial;
                }
                Vector3::new(x, y, 1.0).normalize()
            }
            Lens::KannalaBrandt { k1, k2, k3, k4 } => {
                let theta_d = (xd * xd + yd * yd).sqrt();
                if theta_d < 1e-12 {
                    return Vector3::z();
                }
                // Newton on f(t) = t (1 + k1 t^2 + ...) - theta_d.
                let mut t = theta_d;
                for _ in 0..20 {
                    let t2 = t * t;
                    let f = t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d;
                    let df =
                        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
                    if df.abs() < 1e-12 {
                        break;
                    }
                    t -= f / df;
                }
                let s = t.sin() / theta_d;
                Vector3::new(xd * s, yd * s, t.cos())
            }
        }
    }

    /// Checks the values a config could get wrong.
    pub fn validate(&self) -> Result<(), CameraError> {
        let bad = |key: &'static str, value: String, expected: &'static str| {
            Err(CameraError::Invalid {
                key,
                value,
                expected,
            })
        };
        if self.width == 0 || self.height == 0 {
            return bad(
                "width/height",
                format!("{}x{}", self.width, self.height),
                "both positive",
            );
        }
        for (key, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return bad(key, v.to_string(), "a positive focal length in pixels");
            }
        }
        for (key, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return bad(key, v.to_string(), "a finite principal point in pixels");
            }
        }
        let coeffs: Vec<f64> = match self.lens {
            Lens::PlumbBob { k1, k2, p1, p2, k3 } => vec![k1, k2, p1, p2, k3],
            Lens::KannalaBrandt { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
        };
        if coeffs.iter().any(|c| !c.is_finite()) {
            return bad("distortion", format!("{coeffs:?}"), "finite coefficients");
        }
        Ok(())
    }
}

/// Where a camera sits on the robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mount {
    /// Rotation taking optical-frame vectors to the robot frame.
    pub robot_from_optical: UnitQuaternion<f64>,
    /// Camera centre in the robot frame, metres.
    pub translation_m: Vector3<f64>,
}

impl Mount {
    /// A mount from the camera body's position and roll/pitch/yaw in the robot
    /// frame (degrees; yaw 0 looks forward, 90 left, 180 back; positive pitch
    /// tilts the camera down, as in REP-103).
    pub fn from_xyz_rpy_deg(xyz_m: [f64; 3], rpy_deg: [f64; 3]) -> Self {
        let body = Rotation3::from_euler_angles(
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians(),
        );
        // Columns: the optical x (right), y (down), z (forward) axes in the body frame.
        let body_from_optical = Rotation3::from_matrix_unchecked(Matrix3::new(
            0.0, 0.0, 1.0, //
            -1.0, 0.0, 0.0, //
            0.0, -1.0, 0.0,
        ));
        Self {
            robot_from_optical: UnitQuaternion::from_rotation_matrix(&(body * body_from_optical)),
            translation_m: Vector3::from(xyz_m),
        }
    }

    /// Height of the camera above the robot frame origin (the ground, by convention).
    pub fn height_m(&self) -> f64 {
        self.translation_m.z
    }

    /// Where a ray from this camera (a robot-frame direction, any length)
    /// meets flat ground, `(x_m, y_m)` in the robot frame (x ahead, y
    /// left); `None` for a ray at or above the horizon, or a camera not
    /// above the ground. The one flat-ground projection every stage uses
    /// (POVNav's visual path to ground points, the near-field class map).
    pub fn ground_point_m(&self, ray_robot: &Vector3<f64>) -> Option<(f64, f64)> {
        let h = self.height_m();
        (ray_robot.z < -1e-6 && h > 0.0).then(|| {
            let t = h / -ray_robot.z;
            (
                self.translation_m.x + t * ray_robot.x,
                self.translation_m.y + t * ray_robot.y,
            )
        })
    }
}

/// A camera of the robot: id, name, model and mount.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    pub id: u32,
    pub name: String,
    pub model: CameraModel,
    pub mount: Mount,
}

impl Camera {
    pub fn new(id: u32, name: &str, model: CameraModel, mount: Mount) -> Self {
        Self {
            id,
            name: name.to_string(),
            model,
            mount,
        }
    }

    /// Unit ray through a pixel, in the robot frame.
    pub fn pixel_ray_robot(&self, u: f64, v: f64) -> Vector3<f64> {
        self.mount.robot_from_optical * self.model.unproject(u, v)
    }

    /// Where pixel `(u, v)`'s ray meets flat ground, in the robot frame;
    /// see [`Mount::ground_point_m`].
    pub fn ground_point_m(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        self.mount.ground_point_m(&self.pixel_ray_robot(u, v))
    }

    /// Azimuth of a pixel's ray in the robot frame (0 ahead, counter-clockwise,
    /// in (-pi, pi]); `None` for a ray straight up or down, which has no azimuth.
    pub fn pixel_bearing_rad(&self, u: f64, v: f64) -> Option<f64> {
        let r = self.pixel_ray_robot(u, v);
        (r.x.hypot(r.y) > 1e-9).then(|| r.y.atan2(r.x))
    }

    /// The message that travels with this camera's frames.
    pub fn to_info(&self, stamp: Stamp) -> CameraInfo {
        let (lens, distortion) = match self.model.lens {
            Lens::PlumbBob { k1, k2, p1, p2, k3 } => (LensModel::PINHOLE, [k1, k2, p1, p2, k3]),
            Lens::KannalaBrandt { k1, k2, k3, k4 } => (LensModel::FISHEYE, [k1, k2, k3, k4, 0.0]),
        };
        let q = self.mount.robot_from_optical.quaternion();
        CameraInfo {
            stamp,
            camera_id: self.id,
            name: FixedStr::truncated(&self.name),
            width: self.model.width,
            height: self.model.height,
            lens,
            fx: self.model.fx,
            fy: self.model.fy,
            cx: self.model.cx,
            cy: self.model.cy,
            distortion,
            mount_rotation_xyzw: [q.i, q.j, q.k, q.w],
            mount_translation_m: self.mount.translation_m.into(),
        }
    }

    /// Rebuilds a camera from its message, validating it.
    pub fn from_info(info: &CameraInfo) -> Result<Self, CameraError> {
        let d = info.distortion;
        let lens = match info.lens {
            LensModel::PINHOLE => Lens::PlumbBob {
                k1: d[0],
                k2: d[1],
                p1: d[2],
                p2: d[3],
                k3: d[4],
            },
            LensModel::FISHEYE => Lens::KannalaBrandt {
                k1: d[0],
                k2: d[1],
                k3: d[2],
                k4: d[3],
            },
            other => {
                return Err(CameraError::Invalid {
                    key: "lens",
                    value: other.to_string(),
                    expected: "pinhole or fisheye",
                })
            }
        };
        let model = CameraModel {
            width: info.width,
            height: info.height,
            fx: info.fx,
            fy: info.fy,
            cx: info.cx,
            cy: info.cy,
            lens,
        };
        model.validate()?;
        let [x, y, z, w] = info.mount_rotation_xyzw;
        let q = nalgebra::Quaternion::new(w, x, y, z);
        if !(q.norm() - 1.0).abs().lt(&1e-3) {
            return Err(CameraError::Invalid {
                key: "mount_rotation_xyzw",
                value: format!("{:?}", info.mount_rotation_xyzw),
                expected: "a unit quaternion",
            });
        }
        Ok(Self {
            id: info.camera_id,
            name: info.name.as_str().to_string(),
            model,
            mount: Mount {
                robot_from_optical: UnitQuaternion::from_quaternion(q),
                translation_m: Vector3::from(info.mount_translation_m),
            },
        })
    }
}

/// A camera config or calibration file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("camera {key} = {value}: expected {expected}")]
    Invalid {
        key: &'static str,
        value: String,
        expected: &'static str,
    },
    #[error("reading {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("parsing {path}: {detail}")]
    Parse { path: String, detail: String },
}

/// A camera as written in a stage config (`[[cameras]]` tables).
///
/// ```toml
/// [[cameras]]
/// name = "front"
/// model = "pinhole"            # or "fisheye"
/// width = 1280
/// height = 720
/// fx = 1487.75
/// fy = 1471.06
/// cx = 625.01
/// cy = 376.48
/// distortion = [0.0, 0.0, 0.0, 0.0, 0.0]  # plumb_bob k1 k2 p1 p2 k3 / fisheye k1 k2 k3 k4
/// xyz_m = [0.3, 0.0, 1.2]      # camera centre in the robot frame
/// rpy_deg = [0.0, 5.0, 0.0]    # roll, pitch (down +), yaw (left +)
/// # or take intrinsics from a ROS camera_info YAML instead of fx..distortion:
/// # camera_info = "front.yaml"
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    pub name: String,
    /// Numeric id carried in frame headers; defaults to the position in the list.
    #[serde(default)]
    pub id: Option<u32>,
    #[serde(default)]
    pub model: Option<String>,
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    pub height: Option<u32>,
    #[serde(default)]
    pub fx: Option<f64>,
    #[serde(default)]
    pub fy: Option<f64>,
    #[serde(default)]
    pub cx: Option<f64>,
    #[serde(default)]
    pub cy: Option<f64>,
    #[serde(default)]
    pub distortion: Vec<f64>,
    /// Path of a ROS `camera_info` YAML, relative to the config file.
    #[serde(default)]
    pub camera_info: Option<String>,
    #[serde(default)]
    pub xyz_m: [f64; 3],
    #[serde(default)]
    pub rpy_deg: [f64; 3],
}

impl CameraConfig {
    /// Builds the camera; `base_dir` resolves a relative `camera_info` path.
    pub fn build(&self, default_id: u32, base_dir: &Path) -> Result<Camera, CameraError> {
        let model = match &self.camera_info {
            Some(p) => load_ros_camera_info(&base_dir.join(p))?,
            None => {
                let need = |key: &'static str, v: Option<f64>| {
                    v.ok_or(CameraError::Invalid {
                        key,
                        value: "missing".into(),
                        expected: "a number (or give camera_info = \"file.yaml\")",
                    })
                };
                let model_name = self.model.as_deref().unwrap_or("pinhole");
                let lens = lens_from(model_name, &self.distortion)?;
                CameraModel {
                    width: self.width.ok_or(CameraError::Invalid {
                        key: "width",
                        value: "missing".into(),
                        expected: "image width in pixels",
                    })?,
                    height: self.height.ok_or(CameraError::Invalid {
                        key: "height",
                        value: "missing".into(),
                        expected: "image height in pixels",
                    })?,
                    fx: need("fx", self.fx)?,
                    fy: need("fy", self.fy)?,
                    cx: need("cx", self.cx)?,
                    cy: need("cy", self.cy)?,
                    lens,
                }
            }
        };
        model.validate()?;
        if self
            .xyz_m
            .iter()
            .chain(&self.rpy_deg)
            .any(|v| !v.is_finite())
        {
            return Err(CameraError::Invalid {
                key: "xyz_m/rpy_deg",
                value: format!("{:?} {:?}", self.xyz_m, self.rpy_deg),
                expected: "finite numbers",
            });
        }
        crate::topics::validate_name(&self.name).map_err(|e| CameraError::Invalid {
            key: "name",
            value: self.name.clone(),
            expected: e.why,
        })?;
        Ok(Camera::new(
            self.id.unwrap_or(default_id),
            &self.name,
            model,
            Mount::from_xyz_rpy_deg(self.xyz_m, self.rpy_deg),
        ))
    }
}

fn lens_from(model: &str, d: &[f64]) -> Result<Lens, CameraError> {
    let get = |i: usize| d.get(i).copied().unwrap_or(0.0);
    match model {
        "pinhole" | "plumb_bob" | "rational_polynomial" if d.len() <= 5 => Ok(Lens::PlumbBob {
            k1: get(0),
            k2: get(1),
            p1: get(2),
            p2: get(3),
            k3: get(4),
        }),
        "fisheye" | "equidistant" | "kannala_brandt" if d.len() <= 4 => Ok(Lens::KannalaBrandt {
            k1: get(0),
            k2: get(1),
            k3: get(2),
            k4: get(3),
        }),
        "pinhole" | "plumb_bob" | "fisheye" | "equidistant" | "kannala_brandt" => {
            Err(CameraError::Invalid {
                key: "distortion",
                value: format!("{d:?} ({} values)", d.len()),
                expected: "at most 5 values for plumb_bob (k1 k2 p1 p2 k3), 4 for fisheye (k1..k4)",
            })
        }
        other => Err(CameraError::Invalid {
            key: "model",
            value: other.to_string(),
            expected: "\"pinhole\" (plumb_bob) or \"fisheye\" (equidistant)",
        }),
    }
}

#[derive(Deserialize)]
struct RosMatrix {
    data: Vec<f64>,
}

#[derive(Deserialize)]
struct RosCameraInfo {
    image_width: u32,
    image_height: u32,
    camera_matrix: RosMatrix,
    #[serde(default)]
    distortion_model: Option<String>,
    #[serde(default)]
    distortion_coefficients: Option<RosMatrix>,
}

/// Reads intrinsics from a ROS `camera_info` YAML (as written by
/// `camera_calibration`): `image_width`, `image_height`, `camera_matrix.data`,
/// `distortion_model` (`plumb_bob` or `equidistant`), `distortion_coefficients.data`.
pub fn load_ros_camera_info(path: &Path) -> Result<CameraModel, CameraError> {
    let text = std::fs::read_to_string(path).map_err(|source| CameraError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_ros_camera_info(&text).map_err(|detail| CameraError::Parse {
        path: path.display().to_string(),
        detail,
    })
}

/// Parses the text of a ROS `camera_info` YAML (see [`load_ros_camera_info`]).
pub fn parse_ros_camera_info(text: &str) -> Result<CameraModel, String> {
    let info: RosCameraInfo = serde_norway::from_str(text).map_err(|e| e.to_string())?;
    let k = &info.camera_matrix.data;
    if k.len() != 9 {
        return Err(format!(
            "camera_matrix.data has {} values, expected 9 (row-major 3x3)",
            k.len()
        ));
    }
    let d = info
        .distortion_coefficients
        .map(|m| m.data)
        .unwrap_or_default();
    let model = info.distortion_model.as_deref().unwrap_or("plumb_bob");
    let lens = lens_from(model, &d).map_err(|e| e.to_string())?;
    let m = CameraModel {
        width: info.image_width,
        height: info.image_height,
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
        lens,
    };
    m.validate().map_err(|e| e.to_string())?;
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    fn orfd() -> CameraModel {
        CameraModel::pinhole(1280, 720, 1487.75, 1471.06, 625.01, 376.48)
    }

    #[test]
    fn ground_point_meets_flat_ground_ahead_and_not_above_the_horizon() {
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(80, 60, 40.0, 40.0, 39.5, 29.5),
            Mount::from_xyz_rpy_deg([0.5, 0.0, 1.0], [0.0; 3]),
        );
        // 40 px below the centre at fy = 40: 45 degrees down, 1 m up, so
        // 1 m ahead of the camera, 1.5 m ahead of the robot origin.
        let (x, y) = cam.ground_point_m(39.5, 69.5).unwrap();
        assert!((x - 1.5).abs() < 1e-9 && y.abs() < 1e-9, "({x}, {y})");
        // Left of centre lands left (+y).
        assert!(cam.ground_point_m(0.0, 59.0).unwrap().1 > 0.0);
        assert_eq!(cam.ground_point_m(39.5, 28.5), None);
        assert_eq!(cam.ground_point_m(39.5, 29.5), None, "the horizon line");
        // A camera on the ground sees no ground ahead.
        let low = Camera {
            mount: Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]),
            ..cam
        };
        assert_eq!(low.ground_point_m(39.5, 69.5), None);
    }

    #[test]
    fn pinhole_centre_and_edge_bearings() {
        let cam = Camera::new(
            0,
            "front",
            orfd(),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]),
        );
        assert!(cam.pixel_bearing_rad(625.01, 376.48).unwrap().abs() < 1e-12);
        // Pixel 0 is left of centre: positive (counter-clockwise) bearing of atan(cx/fx).
        let b = cam.pixel_bearing_rad(0.0, 376.48).unwrap();
        assert!((b - (625.01f64 / 1487.75).atan()).abs() < 1e-12, "{b}");
        // A camera yawed 90 degrees left sees its centre at +pi/2.
        let left = Camera::new(
            1,
            "left",
            orfd(),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0, 0.0, 90.0]),
        );
        assert!((left.pixel_bearing_rad(625.01, 376.48).unwrap() - FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn pitch_down_points_centre_ray_at_the_ground() {
        let cam = Camera::new(
            0,
            "f",
            orfd(),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 30.0, 0.0]),
        );
        let r = cam.pixel_ray_robot(625.01, 376.48);
        assert!((r.z - (-0.5)).abs() < 1e-12, "{r}");
        assert!(r.x > 0.0);
    }

    #[test]
    fn plumb_bob_unproject_inverts_project() {
        let mut m = orfd();
        m.lens = Lens::PlumbBob {
            k1: -0.3,
            k2: 0.1,
            p1: 0.001,
            p2: -0.0005,
            k3: 0.0,
        };
        for (u, v) in [(10.0, 20.0), (640.0, 360.0), (1270.0, 700.0)] {
            let ray = m.unproject(u, v);
            let px = m.project(&ray).unwrap();
            assert!(
                (px.x - u).abs() < 1e-6 && (px.y - v).abs() < 1e-6,
                "{u},{v} -> {px}"
            );
        }
    }

    #[test]
    fn fisheye_sees_beyond_ninety_degrees() {
        // Equidistant 190-degree lens: theta_d = theta, f chosen so the image
        // edge is at 95 degrees.
        let f = 320.0 / 95f64.to_radians();
        let m = CameraModel {
            width: 640,
            height: 640,
            fx: f,
            fy: f,
            cx: 320.0,
            cy: 320.0,
            lens: Lens::KannalaBrandt {
                k1: 0.0,
                k2: 0.0,
                k3: 0.0,
                k4: 0.0,
            },
        };
        // Left image edge: 95 degrees off-axis, to the left (optical -x).
        let ray = m.unproject(0.0, 320.0);
        assert!((ray.z.acos().to_degrees() - 95.0).abs() < 1e-9);
        assert!(ray.x < 0.0);
        let back = m.project(&ray).unwrap();
        assert!(back.x.abs() < 1e-9);
        // Mounted facing backwards, that pixel looks 95 degrees to the robot's right... of backwards.
        let cam = Camera::new(
            0,
            "rear",
            m,
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0, 0.0, 180.0]),
        );
        let b = cam.pixel_bearing_rad(0.0, 320.0).unwrap();
        // Optical left of a rear camera is the robot's right: -(180 - 95) degrees.
        assert!(
            (b - (-(PI - 95f64.to_radians()))).abs() < 1e-9,
            "{}",
            b.to_degrees()
        );
    }

    #[test]
    fn camera_info_message_round_trip() {
        let mut m = orfd();
        m.lens = Lens::KannalaBrandt {
            k1: 0.1,
            k2: 0.01,
            k3: 0.0,
            k4: 0.0,
        };
        let cam = Camera::new(
            3,
            "rear",
            m,
            Mount::from_xyz_rpy_deg([-0.4, 0.1, 0.9], [0.0, 10.0, 180.0]),
        );
        let back = Camera::from_info(&cam.to_info(Stamp::default())).unwrap();
        assert_eq!(back.model, cam.model);
        assert!(
            (back.pixel_ray_robot(100.0, 200.0) - cam.pixel_ray_robot(100.0, 200.0)).norm() < 1e-12
        );
    }

    #[test]
    fn ros_camera_info_yaml_is_accepted() {
        let yaml = "image_width: 1280\nimage_height: 720\ncamera_name: front\n\
            camera_matrix:\n  rows: 3\n  cols: 3\n  data: [1487.75, 0, 625.01, 0, 1471.06, 376.48, 0, 0, 1]\n\
            distortion_model: plumb_bob\n\
            distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.1, 0.01, 0, 0, 0]\n\
            rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n";
        let m = parse_ros_camera_info(yaml).unwrap();
        assert_eq!((m.width, m.height), (1280, 720));
        assert_eq!(m.fy, 1471.06);
        assert!(matches!(m.lens, Lens::PlumbBob { k1, .. } if k1 == -0.1));
        let bad = yaml.replace("data: [1487.75, 0, 625.01,", "data: [625.01,");
        assert!(parse_ros_camera_info(&bad)
            .unwrap_err()
            .contains("expected 9"));
    }

    #[test]
    fn config_errors_name_the_key() {
        let cfg: CameraConfig = toml::from_str(
            "name = \"front\"\nwidth = 640\nheight = 360\nfx = -1.0\nfy = 400.0\ncx = 320.0\ncy = 180.0",
        )
        .unwrap();
        let e = cfg.build(0, Path::new(".")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "camera fx = -1: expected a positive focal length in pixels"
        );
        let cfg: CameraConfig =
            toml::from_str("name = \"front\"\nmodel = \"orthographic\"").unwrap();
        assert!(cfg
            .build(0, Path::new("."))
            .unwrap_err()
            .to_string()
            .contains("model = orthographic"));
    }

    #[test]
    fn scaled_model_keeps_bearings() {
        let m = orfd();
        let s = m.scaled_to(640, 360);
        let a = m.unproject(1000.0, 100.0);
        let b = s.unproject((1000.0 + 0.5) * 0.5 - 0.5, (100.0 + 0.5) * 0.5 - 0.5);
        assert!((a - b).norm() < 1e-9);
    }
}
