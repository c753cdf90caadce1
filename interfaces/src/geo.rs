//! The local ENU (east, north, up) frame that poses, goals and maps live in,
//! anchored at a configured GPS fix or at the first fix received.
//!
//! Conversions go through WGS84 ECEF, so they stay exact over the
//! kilometre-scale ranges FITAM plans over (a flat-earth approximation is off
//! by metres at 5 km).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

const WGS84_A: f64 = 6_378_137.0;
const WGS84_F: f64 = 1.0 / 298.257_223_563;
const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);

/// A point on the WGS84 ellipsoid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeoPoint {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    #[serde(default)]
    pub altitude_m: f64,
}

/// A latitude or longitude outside its range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field} = {value} is outside [{min}, {max}] degrees")]
pub struct GeoRangeError {
    pub field: &'static str,
    pub value: f64,
    pub min: f64,
    pub max: f64,
}

impl GeoPoint {
    pub fn new(
        latitude_deg: f64,
        longitude_deg: f64,
        altitude_m: f64,
    ) -> Result<Self, GeoRangeError> {
        let check = |field, value: f64, lim: f64| {
            if value.is_finite() && value.abs() <= lim {
                Ok(())
            } else {
                Err(GeoRangeError {
                    field,
                    value,
                    min: -lim,
                    max: lim,
                })
            }
        };
        check("latitude_deg", latitude_deg, 90.0)?;
        check("longitude_deg", longitude_deg, 180.0)?;
        Ok(Self {
            latitude_deg,
            longitude_deg,
            altitude_m,
        })
    }

    fn to_ecef(self) -> Vector3<f64> {
        let (lat, lon) = (
            self.latitude_deg.to_radians(),
            self.longitude_deg.to_radians(),
        );
        let n = WGS84_A / (1.0 - WGS84_E2 * lat.sin().powi(2)).sqrt();
        Vector3::new(
            (n + self.altitude_m) * lat.cos() * lon.cos(),
            (n + self.altitude_m) * lat.cos() * lon.sin(),
            (n * (1.0 - WGS84_E2) + self.altitude_m) * lat.sin(),
        )
    }

    fn from_ecef(p: Vector3<f64>) -> Self {
        let lon = p.y.atan2(p.x);
        let rho = (p.x * p.x + p.y * p.y).sqrt();
        let mut lat = p.z.atan2(rho * (1.0 - WGS84_E2));
        let mut alt = 0.0;
        // Fixed-point iteration converges to sub-millimetre in a handful of steps.
        for _ in 0..8 {
            let n = WGS84_A / (1.0 - WGS84_E2 * lat.sin().powi(2)).sqrt();
            alt = rho / lat.cos() - n;
            lat = p.z.atan2(rho * (1.0 - WGS84_E2 * n / (n + alt)));
        }
        Self {
            latitude_deg: lat.to_degrees(),
            longitude_deg: lon.to_degrees(),
            altitude_m: alt,
        }
    }
}

/// A local tangent plane at an anchor fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalEnuFrame {
    anchor: GeoPoint,
    anchor_ecef: Vector3<f64>,
    enu_from_ecef: Matrix3<f64>,
}

impl LocalEnuFrame {
    pub fn new(anchor: GeoPoint) -> Self {
        let (lat, lon) = (
            anchor.latitude_deg.to_radians(),
            anchor.longitude_deg.to_radians(),
        );
        let (sl, cl, so, co) = (lat.sin(), lat.cos(), lon.sin(), lon.cos());
        let enu_from_ecef = Matrix3::new(
            -so,
            co,
            0.0, //
            -sl * co,
            -sl * so,
            cl, //
            cl * co,
            cl * so,
            sl,
        );
        Self {
            anchor,
            anchor_ecef: anchor.to_ecef(),
            enu_from_ecef,
        }
    }

    pub fn anchor(&self) -> GeoPoint {
        self.anchor
    }

    /// East, north, up of `p` in metres.
    pub fn to_enu(&self, p: GeoPoint) -> Vector3<f64> {
        self.enu_from_ecef * (p.to_ecef() - self.anchor_ecef)
    }

    /// The geodetic point at `enu` metres from the anchor.
    pub fn to_geodetic(&self, enu: Vector3<f64>) -> GeoPoint {
        GeoPoint::from_ecef(self.anchor_ecef + self.enu_from_ecef.transpose() * enu)
    }
}

/// Holds the ENU frame: a configured anchor, or the first valid fix seen.
#[derive(Debug, Clone, Default)]
pub struct EnuAnchor {
    frame: Option<LocalEnuFrame>,
}

impl EnuAnchor {
    pub fn configured(anchor: GeoPoint) -> Self {
        Self {
            frame: Some(LocalEnuFrame::new(anchor)),
        }
    }

    /// Anchors at the first fix if no anchor is set; returns the frame.
    pub fn observe_fix(&mut self, fix: GeoPoint) -> &LocalEnuFrame {
        self.frame.get_or_insert_with(|| LocalEnuFrame::new(fix))
    }

    pub fn frame(&self) -> Option<&LocalEnuFrame> {
        self.frame.as_ref()
    }
}

/// Bearing (robot frame, counter-clockwise, radians) and distance (metres) of
/// the goal from the robot. A GPS goal needs the ENU anchor; `None` without it
/// or for a goal with bad coordinates.
pub fn goal_in_robot_frame(
    pose: &crate::msg::Pose,
    goal: &crate::msg::NavGoal,
    anchor: Option<&LocalEnuFrame>,
) -> Option<(f64, f64)> {
    use crate::msg::GoalKind;
    let (gx, gy) = match goal.kind {
        GoalKind::LOCAL => (goal.x_m, goal.y_m),
        GoalKind::GPS => {
            let p = GeoPoint::new(goal.latitude_deg, goal.longitude_deg, 0.0).ok()?;
            let enu = anchor?.to_enu(p);
            (enu.x, enu.y)
        }
        _ => return None,
    };
    let (dx, dy) = (gx - pose.position_m[0], gy - pose.position_m[1]);
    if !(dx.is_finite() && dy.is_finite() && pose.yaw_rad.is_finite()) {
        return None;
    }
    let bearing = dy.atan2(dx) - pose.yaw_rad;
    let bearing = (bearing + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
        - std::f64::consts::PI;
    Some((bearing, dx.hypot(dy)))
}

/// What a stage knows about where it is going: the latest pose and goal, and
/// the ENU anchor (configured, or the first valid GPS fix in a pose).
#[derive(Debug, Clone, Default)]
pub struct GoalTracker {
    anchor: EnuAnchor,
    pose: Option<crate::msg::Pose>,
    goal: Option<crate::msg::NavGoal>,
}

impl GoalTracker {
    pub fn new(anchor: EnuAnchor) -> Self {
        Self {
            anchor,
            ..Default::default()
        }
    }

    /// A tracker anchored at the configured latitude/longitude, if both are given.
    pub fn anchored_at(
        latitude_deg: Option<f64>,
        longitude_deg: Option<f64>,
    ) -> Result<Self, GeoRangeError> {
        Ok(match (latitude_deg, longitude_deg) {
            (Some(lat), Some(lon)) => {
                Self::new(EnuAnchor::configured(GeoPoint::new(lat, lon, 0.0)?))
            }
            _ => Self::default(),
        })
    }

    pub fn set_pose(&mut self, pose: crate::msg::Pose) {
        if pose.gps.valid == 1 {
            if let Ok(fix) = GeoPoint::new(
                pose.gps.latitude_deg,
                pose.gps.longitude_deg,
                pose.gps.altitude_m,
            ) {
                self.anchor.observe_fix(fix);
            }
        }
        self.pose = Some(pose);
    }

    pub fn set_goal(&mut self, goal: crate::msg::NavGoal) {
        self.goal = Some(goal);
    }

    /// The latest pose.
    pub fn pose(&self) -> Option<&crate::msg::Pose> {
        self.pose.as_ref()
    }

    /// Bearing and distance of the goal from the robot (see [`goal_in_robot_frame`]).
    pub fn goal_in_robot_frame(&self) -> Option<(f64, f64)> {
        goal_in_robot_frame(
            self.pose.as_ref()?,
            self.goal.as_ref()?,
            self.anchor.frame(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goal_bearing_in_the_robot_frame() {
        use crate::msg::{GoalKind, NavGoal, Pose};
        // Robot at (10, 0) facing north (yaw 90 deg); goal at (0, 0): to its left, 10 m.
        let pose = Pose {
            position_m: [10.0, 0.0, 0.0],
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..Default::default()
        };
        let goal = NavGoal {
            kind: GoalKind::LOCAL,
            x_m: 0.0,
            y_m: 0.0,
            ..Default::default()
        };
        let (b, d) = goal_in_robot_frame(&pose, &goal, None).unwrap();
        assert!((b - std::f64::consts::FRAC_PI_2).abs() < 1e-12 && (d - 10.0).abs() < 1e-12);
        // A GPS goal needs the anchor.
        let gps = NavGoal {
            kind: GoalKind::GPS,
            latitude_deg: 40.4416,
            longitude_deg: -79.9959,
            ..Default::default()
        };
        assert!(goal_in_robot_frame(&pose, &gps, None).is_none());
        let anchor = LocalEnuFrame::new(GeoPoint::new(40.4406, -79.9959, 0.0).unwrap());
        let origin = Pose {
            yaw_rad: 0.0,
            ..Default::default()
        };
        let (b, d) = goal_in_robot_frame(&origin, &gps, Some(&anchor)).unwrap();
        assert!(
            (b - std::f64::consts::FRAC_PI_2).abs() < 1e-3 && (d - 111.04).abs() < 0.3,
            "{b} {d}"
        );
    }

    #[test]
    fn enu_axes_and_round_trip() {
        let anchor = GeoPoint::new(40.4406, -79.9959, 300.0).unwrap();
        let f = LocalEnuFrame::new(anchor);
        assert!(f.to_enu(anchor).norm() < 1e-6);
        // 0.001 deg north is about 111 m north, nothing east.
        let north = f.to_enu(GeoPoint::new(40.4416, -79.9959, 300.0).unwrap());
        assert!((north.y - 111.04).abs() < 0.2, "{north}");
        assert!(north.x.abs() < 1e-6);
        // East is east: longitude grows eastwards.
        let east = f.to_enu(GeoPoint::new(40.4406, -79.9949, 300.0).unwrap());
        assert!(east.x > 84.0 && east.x < 85.5, "{east}");
        // 5 km away the round trip stays at millimetres.
        let p = Vector3::new(3000.0, -4000.0, 12.0);
        let back = f.to_enu(f.to_geodetic(p));
        assert!((back - p).norm() < 1e-3, "{back}");
    }

    #[test]
    fn bad_coordinates_are_named() {
        let e = GeoPoint::new(91.0, 0.0, 0.0).unwrap_err();
        assert_eq!(
            e.to_string(),
            "latitude_deg = 91 is outside [-90, 90] degrees"
        );
        assert!(GeoPoint::new(0.0, f64::NAN, 0.0).is_err());
    }

    #[test]
    fn first_fix_anchors_once() {
        let mut a = EnuAnchor::default();
        assert!(a.frame().is_none());
        let first = GeoPoint::new(1.0, 2.0, 0.0).unwrap();
        a.observe_fix(first);
        a.observe_fix(GeoPoint::new(3.0, 4.0, 0.0).unwrap());
        assert_eq!(a.frame().unwrap().anchor(), first);
    }
}
