//! Foxglove-viewable copies of the topics that have a well-known schema:
//! poses (`foxglove.PoseInFrame`), paths (`foxglove.PosesInFrame`),
//! costmaps (`foxglove.Grid`, cost in s/m as float32) and images
//! (`foxglove.RawImage`, or `foxglove.CompressedImage` for JPEG/PNG), JSON
//! encoded. World-frame data is in frame `map`, robot-frame paths in
//! `base_link`, image data in `camera_<id>`.

use crate::RecordingError;
use base64::Engine;
use farsight_interfaces::msg::*;
use farsight_interfaces::topics::{kind_of, TopicKind};
use farsight_interfaces::transport::wire;
use serde_json::{json, Value};

fn time(ns: u64) -> Value {
    json!({ "sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000 })
}

fn pose_xy_yaw(x: f64, y: f64, z: f64, yaw: f64) -> Value {
    json!({
        "position": { "x": x, "y": y, "z": z },
        "orientation": { "x": 0.0, "y": 0.0, "z": (yaw / 2.0).sin(), "w": (yaw / 2.0).cos() },
    })
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The Foxglove schema name and JSON message for one wire message of
/// `topic`, or `None` where no well-known schema fits.
pub fn to_json(
    topic: &str,
    bytes: &[u8],
) -> Result<Option<(&'static str, Vec<u8>)>, RecordingError> {
    let v = match kind_of(topic) {
        Some(TopicKind::Pose) => {
            let p: Pose = wire::decode_message(bytes)?;
            let [x, y, z] = p.position_m;
            (
                "foxglove.PoseInFrame",
                json!({
                    "timestamp": time(p.stamp.capture_time_ns),
                    "frame_id": "map",
                    "pose": pose_xy_yaw(x, y, z, p.yaw_rad),
                }),
            )
        }
        Some(TopicKind::Path) => {
            let p: Path = wire::decode_message(bytes)?;
            let frame = match p.frame {
                PathFrame::WORLD => "map".to_string(),
                PathFrame::ROBOT => "base_link".to_string(),
                _ => format!("camera_{}", p.camera_id),
            };
            let poses: Vec<Value> = p
                .points
                .as_slice()
                .iter()
                .map(|q| pose_xy_yaw(q[0] as f64, q[1] as f64, 0.0, 0.0))
                .collect();
            (
                "foxglove.PosesInFrame",
                json!({ "timestamp": time(p.stamp.capture_time_ns), "frame_id": frame, "poses": poses }),
            )
        }
        Some(TopicKind::Costmap) => {
            let (h, cells) = wire::decode_slice::<CostmapHeader, CostCell>(bytes)?;
            let res = h.resolution_m as f64;
            // Foxglove grids grow from their origin along +x and +y: row 0 is
            // the southmost row, where farsight's row 0 is the northmost.
            let w = h.width as usize;
            let mut data = Vec::with_capacity(cells.len() * 4);
            for row in cells.chunks(w.max(1)).rev() {
                for c in row {
                    data.extend_from_slice(&c.cost_s_per_m.to_le_bytes());
                }
            }
            let rows = cells.len() / w.max(1);
            let origin_y = h.y_max_m - (rows as f64 - 0.5) * res;
            (
                "foxglove.Grid",
                json!({
                    "timestamp": time(h.stamp.capture_time_ns),
                    "frame_id": "map",
                    "pose": pose_xy_yaw(h.x_min_m - 0.5 * res, origin_y, 0.0, 0.0),
                    "column_count": h.width,
                    "cell_size": { "x": res, "y": res },
                    "row_stride": w * 4,
                    "cell_stride": 4,
                    "fields": [{ "name": "cost_s_per_m", "offset": 0, "type": 7 }],
                    "data": b64(&data),
                }),
            )
        }
        Some(TopicKind::Image) => {
            let (h, data) = wire::split_slice::<ImageHeader>(bytes)?;
            let frame = format!("camera_{}", h.camera_id);
            let stamp = time(h.stamp.capture_time_ns);
            let encoding = match h.encoding {
                PixelEncoding::JPEG | PixelEncoding::PNG => {
                    let format = if h.encoding == PixelEncoding::JPEG {
                        "jpeg"
                    } else {
                        "png"
                    };
                    let v = json!({ "timestamp": stamp, "frame_id": frame, "format": format, "data": b64(data) });
                    return Ok(Some((
                        "foxglove.CompressedImage",
                        serde_json::to_vec(&v).expect("json"),
                    )));
                }
                PixelEncoding::RGB8 => "rgb8",
                PixelEncoding::BGR8 => "bgr8",
                PixelEncoding::RGBA8 => "rgba8",
                PixelEncoding::MONO8 => "mono8",
                PixelEncoding::MONO16 => "mono16",
                PixelEncoding::F32 => "32FC1",
                PixelEncoding::YUYV => "yuyv",
                _ => return Ok(None),
            };
            (
                "foxglove.RawImage",
                json!({
                    "timestamp": stamp,
                    "frame_id": frame,
                    "width": h.width,
                    "height": h.height,
                    "encoding": encoding,
                    "step": h.stride_bytes,
                    "data": b64(data),
                }),
            )
        }
        _ => return Ok(None),
    };
    Ok(Some((
        v.0,
        serde_json::to_vec(&v.1).expect("json values serialise"),
    )))
}

/// A JSON schema for the Foxglove channel: the app recognises the schema
/// by name, so this only records the name and that messages are objects.
pub fn json_schema(name: &str) -> String {
    json!({ "title": name, "type": "object" }).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_becomes_a_pose_in_frame_with_the_yaw_as_a_quaternion() {
        let p = Pose {
            stamp: Stamp::new(3, 1_500_000_000),
            position_m: [1.0, 2.0, 0.0],
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..Default::default()
        };
        let (schema, json) = to_json("state/pose", &wire::encode_message(&p).unwrap())
            .unwrap()
            .unwrap();
        assert_eq!(schema, "foxglove.PoseInFrame");
        let v: Value = serde_json::from_slice(&json).unwrap();
        assert_eq!(v["timestamp"]["sec"], 1);
        assert_eq!(v["timestamp"]["nsec"], 500_000_000);
        assert_eq!(v["pose"]["position"]["y"], 2.0);
        let w = v["pose"]["orientation"]["w"].as_f64().unwrap();
        assert!((w - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    }

    #[test]
    fn costmap_rows_are_flipped_to_grow_north_and_images_keep_their_bytes() {
        let h = CostmapHeader {
            width: 2,
            height: 2,
            resolution_m: 1.0,
            x_min_m: 10.0,
            y_max_m: 20.0,
            ..Default::default()
        };
        let cell = |c| CostCell {
            cost_s_per_m: c,
            variance: 0.0,
        };
        let cells = [cell(1.0), cell(2.0), cell(3.0), cell(4.0)];
        let (schema, json) = to_json("costmap/fused", &wire::encode_slice(&h, &cells).unwrap())
            .unwrap()
            .unwrap();
        assert_eq!(schema, "foxglove.Grid");
        let v: Value = serde_json::from_slice(&json).unwrap();
        let data = base64::engine::general_purpose::STANDARD
            .decode(v["data"].as_str().unwrap())
            .unwrap();
        let first = f32::from_le_bytes(data[0..4].try_into().unwrap());
        assert_eq!(first, 3.0, "the southern row (farsight row 1) comes first");
        assert_eq!(v["pose"]["position"]["y"], 18.5);
        assert_eq!(v["pose"]["position"]["x"], 9.5);

        let ih = ImageHeader::packed(Stamp::new(1, 2), 4, 2, 1, PixelEncoding::RGB8);
        let (schema, json) = to_json(
            "camera/front/image",
            &wire::encode_slice(&ih, &[1u8, 2, 3, 4, 5, 6]).unwrap(),
        )
        .unwrap()
        .unwrap();
        assert_eq!(schema, "foxglove.RawImage");
        let v: Value = serde_json::from_slice(&json).unwrap();
        assert_eq!(
            (v["encoding"].as_str(), v["frame_id"].as_str()),
            (Some("rgb8"), Some("camera_4"))
        );
        assert_eq!(v["data"], "AQIDBAUG");
        assert!(to_json("nav/subgoal", &[]).unwrap().is_none());
    }
}
