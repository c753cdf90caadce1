//! The operator's goals, e-stop and teleop from the Foxglove app.
//!
//! Only the laptop's server (`farsight foxglove --connect`) takes them, and
//! only when its zenoh login may command the robot: the robot's router lets
//! the `operator` user put on the bridge's imported keys (`nav/goal`,
//! `safety/estop`, `cmd/teleop`) and nobody else
//! (`farsight_bridge::acl`). The server checks the same rule first, so a
//! refused message is refused here, logged and answered with a status the
//! app shows, instead of vanishing at the router. What it accepts goes to
//! the robot as farsight messages: the goal to the planner, teleop to the
//! command mux's operator input (never `cmd/velocity`), the e-stop to the
//! mux's latch.
//!
//! The app's e-stop is a convenience, not a safety function: it travels
//! over a WebSocket, a laptop's network and zenoh, any of which may be down
//! when it is pressed. The robot's own e-stop and the mux's deadman are the
//! safety functions.
//!
//! What the app publishes (JSON, the encoding the server supports):
//!
//! | topic | schema | becomes |
//! | --- | --- | --- |
//! | `/nav/goal` | `geometry_msgs/PoseStamped`, `geometry_msgs/PointStamped` (the 3-D panel's publish tools; ROS 2 `.../msg/...` names too) in frame `map` or `odom` | a local goal at (x, y) |
//! | `/nav/goal` | `farsight/GpsGoal`: `{"latitude_deg", "longitude_deg", "tolerance_m"}` | a GPS goal |
//! | `/cmd/teleop` | `geometry_msgs/Twist` (the Teleop panel) | `linear.x` m/s, `angular.z` rad/s |
//! | `/safety/estop` | `farsight/EStop`: `{"active": "pressed" \| "released" \| "clear"}` | the mux's latch |
//! | `/safety/estop` | `std_msgs/Bool`: `{"data": true}` pressed, `false` released | |

use farsight_interfaces::fixed::FixedStr;
use farsight_interfaces::msg::{CommandReason, EStop, GoalKind, NavGoal, Stamp, VelocityCommand};
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// The Foxglove topics the operator may publish on.
pub const ACCEPTED_TOPICS: [&str; 3] = ["/nav/goal", "/cmd/teleop", "/safety/estop"];

/// The largest message from the app that is parsed at all.
pub const MAX_PAYLOAD_BYTES: usize = 64 * 1024;

/// Limits on what the app may send; `[operator]` in the `farsight
/// foxglove` config file, every key optional (defaults shown).
///
/// ```toml
/// [operator]
/// teleop_max_linear_mps = 2.0    # a faster teleop command is refused, not clamped
/// teleop_max_angular_radps = 2.0
/// teleop_ttl_ms = 500            # how long the base may obey one teleop message
///                                # (the mux caps it at its input's max_ttl_s): set the
///                                # Teleop panel's publish rate to 5 Hz or more
/// goal_tolerance_m = 2.0         # a goal's tolerance when the message has none
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OperatorConfig {
    pub teleop_max_linear_mps: f64,
    pub teleop_max_angular_radps: f64,
    pub teleop_ttl_ms: u16,
    pub goal_tolerance_m: f64,
}

impl Default for OperatorConfig {
    fn default() -> Self {
        Self {
            teleop_max_linear_mps: 2.0,
            teleop_max_angular_radps: 2.0,
            teleop_ttl_ms: 500,
            goal_tolerance_m: 2.0,
        }
    }
}

impl OperatorConfig {
    /// Every key in its range, or the first that is not, named.
    pub fn validate(&self) -> Result<(), String> {
        for (key, value, max) in [
            ("teleop_max_linear_mps", self.teleop_max_linear_mps, 10.0),
            (
                "teleop_max_angular_radps",
                self.teleop_max_angular_radps,
                10.0,
            ),
            ("goal_tolerance_m", self.goal_tolerance_m, 1000.0),
            ("teleop_ttl_ms", f64::from(self.teleop_ttl_ms), 5000.0),
        ] {
            if !(value > 0.0 && value <= max) {
                return Err(format!(
                    "config key `operator.{key}` = {value}: expected 0 < x <= {max}"
                ));
            }
        }
        Ok(())
    }
}

/// A message from the app, as the farsight message it becomes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OperatorCommand {
    Goal(NavGoal),
    Teleop(VelocityCommand),
    EStop(EStop),
}

impl OperatorCommand {
    /// The farsight topic it is published on.
    pub fn topic(&self) -> &'static str {
        match self {
            OperatorCommand::Goal(_) => "nav/goal",
            OperatorCommand::Teleop(_) => "cmd/teleop",
            OperatorCommand::EStop(_) => "safety/estop",
        }
    }
}

/// Why a message from the app was not sent to the robot.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    #[error("{0}")]
    NotOperator(String),
    #[error("topic {0}: the operator may publish only on {ACCEPTED_TOPICS:?}")]
    Topic(String),
    #[error("topic {topic}: encoding {encoding:?}, the server takes json")]
    Encoding { topic: String, encoding: String },
    #[error("topic {topic}: schema {schema:?} is not one it takes ({expected})")]
    Schema {
        topic: String,
        schema: String,
        expected: &'static str,
    },
    #[error("topic {topic} ({schema}): {why}")]
    Bad {
        topic: String,
        schema: String,
        why: String,
    },
}

/// Whether the zenoh login `user` may command the robot: the robot's router
/// lets only `operator` (the ACL's command user) put on the imported keys.
pub fn may_command(user: Option<&str>, operator: &str) -> Result<(), Refusal> {
    match user {
        Some(u) if u == operator => Ok(()),
        Some(u) => Err(Refusal::NotOperator(format!(
            "zenoh user {u:?} may not command the robot: only {operator:?} may \
             (the robot's router refuses anyone else's goals, e-stop and teleop); \
             start farsight foxglove with --user {operator}"
        ))),
        None => Err(Refusal::NotOperator(format!(
            "no zenoh login (--user): only {operator:?} may command the robot"
        ))),
    }
}

/// One message the app published on a client channel, as the farsight
/// message it becomes, stamped `stamp` (the laptop's clock: the mux times
/// a teleop command from its receipt, not from this stamp).
pub fn command_from_client(
    topic: &str,
    encoding: &str,
    schema: &str,
    payload: &[u8],
    stamp: Stamp,
    source: &str,
    config: &OperatorConfig,
) -> Result<OperatorCommand, Refusal> {
    if !ACCEPTED_TOPICS.contains(&topic) {
        return Err(Refusal::Topic(topic.into()));
    }
    if encoding != "json" {
        return Err(Refusal::Encoding {
            topic: topic.into(),
            encoding: encoding.into(),
        });
    }
    let bad = |why: String| Refusal::Bad {
        topic: topic.into(),
        schema: schema.into(),
        why,
    };
    // A goal, a twist or an e-stop is a few hundred bytes: anything much
    // larger is not one, and is not parsed.
    if payload.len() > MAX_PAYLOAD_BYTES {
        return Err(bad(format!(
            "{} bytes: larger than the {MAX_PAYLOAD_BYTES} a command may be",
            payload.len()
        )));
    }
    let json: Value = serde_json::from_slice(payload).map_err(|e| bad(format!("not JSON: {e}")))?;
    // ROS 2 names ("geometry_msgs/msg/Twist") and ROS 1 names are the same message.
    let schema_key = schema.replace("/msg/", "/");
    match (topic, schema_key.as_str()) {
        ("/nav/goal", "geometry_msgs/PoseStamped" | "geometry_msgs/PointStamped") => {
            let frame = json
                .pointer("/header/frame_id")
                .and_then(Value::as_str)
                .unwrap_or("");
            if frame != "map" && frame != "odom" {
                return Err(bad(format!(
                    "header.frame_id {frame:?}: a goal is taken in \"map\" or \"odom\" \
                     (set the 3-D panel's display frame to map)"
                )));
            }
            let position = if schema_key.ends_with("PoseStamped") {
                "/pose/position"
            } else {
                "/point"
            };
            let x_m = finite(&json, &format!("{position}/x")).map_err(bad)?;
            let y_m = finite(&json, &format!("{position}/y")).map_err(bad)?;
            for (name, v) in [("x", x_m), ("y", y_m)] {
                if v.abs() > 1e7 {
                    return Err(bad(format!("{name} = {v:e} m: beyond 10,000 km")));
                }
            }
            Ok(OperatorCommand::Goal(NavGoal {
                stamp,
                kind: GoalKind::LOCAL,
                x_m,
                y_m,
                tolerance_m: config.goal_tolerance_m as f32,
                ..Default::default()
            }))
        }
        ("/nav/goal", "farsight/GpsGoal") => {
            let latitude_deg = finite(&json, "/latitude_deg").map_err(bad)?;
            let longitude_deg = finite(&json, "/longitude_deg").map_err(bad)?;
            if latitude_deg.abs() > 90.0 || longitude_deg.abs() > 180.0 {
                return Err(bad(format!(
                    "({latitude_deg}, {longitude_deg}) is not a latitude/longitude in degrees"
                )));
            }
            let tolerance_m = match json.get("tolerance_m") {
                None => config.goal_tolerance_m,
                Some(_) => finite(&json, "/tolerance_m").map_err(bad)?,
            };
            if !(tolerance_m > 0.0 && tolerance_m <= 1000.0) {
                return Err(bad(format!(
                    "tolerance_m = {tolerance_m}: expected 0 < x <= 1000 m"
                )));
            }
            Ok(OperatorCommand::Goal(NavGoal {
                stamp,
                kind: GoalKind::GPS,
                latitude_deg,
                longitude_deg,
                tolerance_m: tolerance_m as f32,
                ..Default::default()
            }))
        }
        ("/nav/goal", _) => Err(Refusal::Schema {
            topic: topic.into(),
            schema: schema.into(),
            expected: "geometry_msgs/PoseStamped, geometry_msgs/PointStamped or farsight/GpsGoal",
        }),
        ("/cmd/teleop", "geometry_msgs/Twist") => {
            let linear = finite(&json, "/linear/x").map_err(bad)?;
            let angular = finite(&json, "/angular/z").map_err(bad)?;
            if linear.abs() > config.teleop_max_linear_mps {
                return Err(bad(format!(
                    "linear.x = {linear} m/s: beyond teleop_max_linear_mps = {}",
                    config.teleop_max_linear_mps
                )));
            }
            if angular.abs() > config.teleop_max_angular_radps {
                return Err(bad(format!(
                    "angular.z = {angular} rad/s: beyond teleop_max_angular_radps = {}",
                    config.teleop_max_angular_radps
                )));
            }
            Ok(OperatorCommand::Teleop(VelocityCommand {
                stamp,
                linear_mps: linear as f32,
                angular_radps: angular as f32,
                reason: CommandReason::TELEOP,
                ttl_ms: config.teleop_ttl_ms,
            }))
        }
        ("/cmd/teleop", _) => Err(Refusal::Schema {
            topic: topic.into(),
            schema: schema.into(),
            expected: "geometry_msgs/Twist",
        }),
        ("/safety/estop", "farsight/EStop") => {
            let raw = json.get("active");
            let active = match raw.and_then(Value::as_str) {
                Some("pressed") => EStop::PRESSED,
                Some("released") => EStop::RELEASED,
                Some("clear") => EStop::CLEAR,
                _ => {
                    return Err(bad(format!(
                        "active = {}: expected \"pressed\", \"released\" or \"clear\"",
                        raw.map_or_else(|| "missing".to_string(), Value::to_string)
                    )))
                }
            };
            Ok(estop(stamp, active, source))
        }
        ("/safety/estop", "std_msgs/Bool") => match json.get("data").and_then(Value::as_bool) {
            Some(true) => Ok(estop(stamp, EStop::PRESSED, source)),
            Some(false) => Ok(estop(stamp, EStop::RELEASED, source)),
            None => Err(bad(
                "data: expected true (pressed) or false (released)".into()
            )),
        },
        _ => Err(Refusal::Schema {
            topic: topic.into(),
            schema: schema.into(),
            expected: "farsight/EStop or std_msgs/Bool",
        }),
    }
}

fn estop(stamp: Stamp, active: u8, source: &str) -> OperatorCommand {
    // The source names who pressed it in the mux's log; cut to fit.
    let mut s = source;
    while s.len() > 32 {
        let mut end = 32;
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        s = &s[..end];
    }
    OperatorCommand::EStop(EStop {
        stamp,
        active,
        source: FixedStr::new(s).unwrap_or_default(),
    })
}

/// The finite number at JSON pointer `at`.
fn finite(json: &Value, at: &str) -> Result<f64, String> {
    let field = at.trim_start_matches('/').replace('/', ".");
    match json.pointer(at) {
        None => Err(format!("{field}: missing")),
        Some(v) => match v.as_f64() {
            Some(x) if x.is_finite() => Ok(x),
            _ => Err(format!("{field} = {v}: expected a finite number")),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn take(topic: &str, schema: &str, json: &str) -> Result<OperatorCommand, Refusal> {
        command_from_client(
            topic,
            "json",
            schema,
            json.as_bytes(),
            Stamp::new(3, 42),
            "foxglove operator",
            &OperatorConfig::default(),
        )
    }

    #[test]
    fn only_the_operator_login_may_command() {
        assert!(may_command(Some("operator"), "operator").is_ok());
        let e = may_command(Some("laptop"), "operator")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("\"laptop\"") && e.contains("--user operator"),
            "{e}"
        );
        assert!(may_command(None, "operator").is_err());
    }

    #[test]
    fn the_3d_panels_pose_and_point_become_local_goals_in_map() {
        let pose = r#"{"header":{"stamp":{"sec":1,"nsec":0},"frame_id":"map"},
            "pose":{"position":{"x":22.5,"y":-3,"z":0},"orientation":{"x":0,"y":0,"z":0,"w":1}}}"#;
        for schema in ["geometry_msgs/PoseStamped", "geometry_msgs/msg/PoseStamped"] {
            let OperatorCommand::Goal(g) = take("/nav/goal", schema, pose).unwrap() else {
                panic!("not a goal")
            };
            assert_eq!((g.kind, g.x_m, g.y_m), (GoalKind::LOCAL, 22.5, -3.0));
            assert_eq!(g.stamp, Stamp::new(3, 42));
            assert_eq!(g.tolerance_m, 2.0);
        }
        let point = r#"{"header":{"frame_id":"odom"},"point":{"x":1,"y":2,"z":0}}"#;
        let c = take("/nav/goal", "geometry_msgs/PointStamped", point).unwrap();
        assert_eq!(c.topic(), "nav/goal");
        assert!(matches!(c, OperatorCommand::Goal(g) if g.x_m == 1.0 && g.y_m == 2.0));
        // Another frame would need the robot's pose at the click: refused, named.
        let e = take(
            "/nav/goal",
            "geometry_msgs/PointStamped",
            &point.replace("odom", "base_link"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("\"base_link\""), "{e}");
    }

    #[test]
    fn a_gps_goal_is_checked_for_degrees() {
        let c = take(
            "/nav/goal",
            "farsight/GpsGoal",
            r#"{"latitude_deg":47.1,"longitude_deg":8.5}"#,
        )
        .unwrap();
        assert!(matches!(c, OperatorCommand::Goal(g)
            if g.kind == GoalKind::GPS && g.latitude_deg == 47.1 && g.tolerance_m == 2.0));
        let e = take(
            "/nav/goal",
            "farsight/GpsGoal",
            r#"{"latitude_deg":147.1,"longitude_deg":8.5}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("147.1"), "{e}");
    }

    #[test]
    fn teleop_is_the_twists_forward_and_yaw_rates_within_the_limits() {
        let c = take(
            "/cmd/teleop",
            "geometry_msgs/Twist",
            r#"{"linear":{"x":0.4,"y":0,"z":0},"angular":{"x":0,"y":0,"z":-0.25}}"#,
        )
        .unwrap();
        assert_eq!(c.topic(), "cmd/teleop");
        let OperatorCommand::Teleop(v) = c else {
            panic!("not teleop")
        };
        assert_eq!((v.linear_mps, v.angular_radps), (0.4, -0.25));
        assert_eq!((v.reason, v.ttl_ms), (CommandReason::TELEOP, 500));
        // Too fast is refused, not clamped: the operator sees why.
        let e = take(
            "/cmd/teleop",
            "geometry_msgs/Twist",
            r#"{"linear":{"x":3.0},"angular":{"z":0}}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("linear.x = 3") && e.contains("teleop_max_linear_mps"),
            "{e}"
        );
    }

    #[test]
    fn the_estop_latches_releases_and_clears() {
        for (json, active) in [
            (r#"{"active":"pressed"}"#, EStop::PRESSED),
            (r#"{"active":"released"}"#, EStop::RELEASED),
            (r#"{"active":"clear"}"#, EStop::CLEAR),
        ] {
            let c = take("/safety/estop", "farsight/EStop", json).unwrap();
            assert!(matches!(c, OperatorCommand::EStop(e)
                if e.active == active && e.source.as_str() == "foxglove operator"));
        }
        let c = take("/safety/estop", "std_msgs/Bool", r#"{"data":true}"#).unwrap();
        assert!(matches!(c, OperatorCommand::EStop(e) if e.active == EStop::PRESSED));
        // A long source name is cut, not refused: the e-stop must go out.
        let long = "x".repeat(40);
        let c = command_from_client(
            "/safety/estop",
            "json",
            "std_msgs/Bool",
            br#"{"data":true}"#,
            Stamp::default(),
            &long,
            &OperatorConfig::default(),
        )
        .unwrap();
        assert!(matches!(c, OperatorCommand::EStop(e) if e.source.as_str().len() == 32));
    }

    #[test]
    fn garbage_is_refused_naming_the_topic_and_the_field() {
        let cases: [(&str, &str, &str, &[&str]); 8] = [
            (
                "/cmd/velocity",
                "geometry_msgs/Twist",
                "{}",
                &["/cmd/velocity"],
            ),
            (
                "/cmd/teleop",
                "geometry_msgs/Twist",
                "{not json",
                &["not JSON"],
            ),
            (
                "/cmd/teleop",
                "geometry_msgs/Twist",
                r#"{"linear":{"x":"fast"},"angular":{"z":0}}"#,
                &["linear.x = \"fast\""],
            ),
            (
                "/cmd/teleop",
                "geometry_msgs/Twist",
                r#"{"angular":{"z":0}}"#,
                &["linear.x: missing"],
            ),
            (
                "/cmd/teleop",
                "std_msgs/String",
                "{}",
                &["std_msgs/String", "Twist"],
            ),
            (
                "/nav/goal",
                "geometry_msgs/PoseStamped",
                r#"{"header":{"frame_id":"map"},"pose":{"position":{"x":1e300,"y":0}}}"#,
                &["x = 1e300"],
            ),
            (
                "/safety/estop",
                "farsight/EStop",
                r#"{"active":1}"#,
                &["active = 1"],
            ),
            (
                "/safety/estop",
                "std_msgs/Bool",
                r#"{"data":"yes"}"#,
                &["data"],
            ),
        ];
        for (topic, schema, json, needles) in cases {
            let e = take(topic, schema, json).unwrap_err().to_string();
            assert!(e.contains(topic), "{e}");
            for n in needles {
                assert!(e.contains(n), "{topic} {json}: {e:?} lacks {n:?}");
            }
        }
        let huge = format!(
            r#"{{"data":true,"pad":"{}"}}"#,
            "x".repeat(MAX_PAYLOAD_BYTES)
        );
        let e = take("/safety/estop", "std_msgs/Bool", &huge)
            .unwrap_err()
            .to_string();
        assert!(e.contains("larger than the 65536"), "{e}");
        let e = command_from_client(
            "/cmd/teleop",
            "cdr",
            "geometry_msgs/msg/Twist",
            &[0, 1],
            Stamp::default(),
            "",
            &OperatorConfig::default(),
        )
        .unwrap_err();
        assert!(matches!(e, Refusal::Encoding { .. }), "{e}");
    }

    #[test]
    fn a_config_out_of_range_is_named() {
        let c = OperatorConfig {
            teleop_max_linear_mps: f64::NAN,
            ..Default::default()
        };
        let e = c.validate().unwrap_err();
        assert!(
            e.contains("operator.teleop_max_linear_mps") && e.contains("NaN"),
            "{e}"
        );
        assert!(OperatorConfig::default().validate().is_ok());
    }
}
