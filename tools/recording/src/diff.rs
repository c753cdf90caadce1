//! Comparing a run against a golden recording, topic by topic and frame by
//! frame (messages are matched by the sequence number in their stamp):
//! integers and bytes exactly, floats within a tolerance. Every difference
//! names the topic, the sequence number and the field. Messages with
//! sequence number 0 derive from no frame (the servo's stops before its
//! first input and at shutdown) and are not compared.

use crate::read::Recording;
use crate::{RecordingError, MESSAGE_ENCODING};
use farsight_interfaces::msg::*;
use farsight_interfaces::topics::{kind_of, TopicKind};
use farsight_interfaces::transport::wire;
use serde_json::Value;
use std::collections::BTreeMap;

/// How far floats may differ: `|a - b| <= abs + rel * max(|a|, |b|)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    pub abs: f64,
    pub rel: f64,
}

impl Default for Tolerance {
    fn default() -> Self {
        Self {
            abs: 1e-4,
            rel: 1e-4,
        }
    }
}

impl Tolerance {
    fn close(&self, a: f64, b: f64) -> bool {
        (a.is_nan() && b.is_nan())
            || a == b
            || (a - b).abs() <= self.abs + self.rel * a.abs().max(b.abs())
    }
}

/// One difference between the golden run and this one.
#[derive(Debug, Clone, PartialEq)]
pub struct Mismatch {
    pub topic: String,
    pub seq: u64,
    pub field: String,
    pub expected: String,
    pub got: String,
}

impl std::fmt::Display for Mismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} seq {} {}: expected {}, got {}",
            self.topic, self.seq, self.field, self.expected, self.got
        )
    }
}

/// A decoded message: its fields as JSON, plus the slice elements (bytes
/// compared exactly, or floats compared with the tolerance).
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    pub fields: Value,
    pub bytes: Option<Vec<u8>>,
    pub floats: Option<Vec<f32>>,
}

fn json<T: serde::Serialize>(v: &T) -> Value {
    serde_json::to_value(v).expect("farsight messages serialise to JSON")
}

fn floats(body: &[u8]) -> Vec<f32> {
    body.chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect()
}

/// Decodes one wire message of `topic` for comparison.
pub fn decode(topic: &str, bytes: &[u8]) -> Result<Decoded, RecordingError> {
    let kind = kind_of(topic).ok_or_else(|| RecordingError::Topic {
        topic: topic.into(),
        why: "not a farsight topic".into(),
    })?;
    fn fixed<M: serde::de::DeserializeOwned + serde::Serialize>(
        b: &[u8],
    ) -> Result<Decoded, RecordingError> {
        let m: M = wire::decode_message(b)?;
        Ok(Decoded {
            fields: json(&m),
            bytes: None,
            floats: None,
        })
    }
    Ok(match kind {
        TopicKind::Image => {
            let (h, body) = wire::split_slice::<ImageHeader>(bytes)?;
            let (b, f) = if h.encoding == PixelEncoding::F32 {
                (None, Some(floats(body)))
            } else {
                (Some(body.to_vec()), None)
            };
            Decoded {
                fields: json(&h),
                bytes: b,
                floats: f,
            }
        }
        TopicKind::Tensor => {
            let (h, body) = wire::split_slice::<TensorHeader>(bytes)?;
            Decoded {
                fields: json(&h),
                bytes: None,
                floats: Some(floats(body)),
            }
        }
        TopicKind::Costmap => {
            let (h, body) = wire::split_slice::<CostmapHeader>(bytes)?;
            Decoded {
                fields: json(&h),
                bytes: None,
                floats: Some(floats(body)),
            }
        }
        TopicKind::PolarBins => {
            // Cost, variance and probability are floats; the class id is exact.
            let (h, cells) = wire::decode_slice::<PolarBinsHeader, PolarCell>(bytes)?;
            let f = cells
                .iter()
                .flat_map(|c| [c.cost_s_per_m, c.variance, c.probability])
                .collect();
            let ids = cells
                .iter()
                .flat_map(|c| c.class_id.to_le_bytes())
                .collect();
            Decoded {
                fields: json(&h),
                bytes: Some(ids),
                floats: Some(f),
            }
        }
        TopicKind::CameraInfo => fixed::<CameraInfo>(bytes)?,
        TopicKind::AngularBins => fixed::<AngularBins>(bytes)?,
        TopicKind::Subgoal => fixed::<Subgoal>(bytes)?,
        TopicKind::Path => fixed::<Path>(bytes)?,
        TopicKind::Goal => fixed::<NavGoal>(bytes)?,
        TopicKind::Pose => fixed::<Pose>(bytes)?,
        TopicKind::VelocityCommand => fixed::<VelocityCommand>(bytes)?,
        TopicKind::EStop => fixed::<EStop>(bytes)?,
        TopicKind::Health => fixed::<StageHealth>(bytes)?,
    })
}

fn compare_values(
    path: &str,
    a: &Value,
    b: &Value,
    tol: Tolerance,
    out: &mut Vec<(String, String, String)>,
) {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let exact = (x.is_u64() || x.is_i64()) && (y.is_u64() || y.is_i64());
            let same = if exact {
                x == y
            } else {
                tol.close(
                    x.as_f64().unwrap_or(f64::NAN),
                    y.as_f64().unwrap_or(f64::NAN),
                )
            };
            if !same {
                out.push((path.to_string(), x.to_string(), y.to_string()));
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                compare_values(&format!("{path}[{i}]"), p, q, tol, out);
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            for (k, p) in x {
                let sub = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                match y.get(k) {
                    Some(q) => compare_values(&sub, p, q, tol, out),
                    None => out.push((sub, p.to_string(), "(missing)".into())),
                }
            }
        }
        // serde_json writes NaN as null: equal nulls are equal floats.
        _ if a == b => {}
        _ => out.push((path.to_string(), a.to_string(), b.to_string())),
    }
}

/// The differences between two decoded messages, as (field, expected, got).
pub fn compare_decoded(a: &Decoded, b: &Decoded, tol: Tolerance) -> Vec<(String, String, String)> {
    let mut out = Vec::new();
    compare_values("", &a.fields, &b.fields, tol, &mut out);
    match (&a.bytes, &b.bytes) {
        (Some(x), Some(y)) if x.len() != y.len() => {
            out.push(("data.len".into(), x.len().to_string(), y.len().to_string()))
        }
        (Some(x), Some(y)) => {
            if let Some(i) = x.iter().zip(y).position(|(p, q)| p != q) {
                let n = x.iter().zip(y).filter(|(p, q)| p != q).count();
                out.push((
                    format!("data[{i}] (bytes; {n} differ)"),
                    x[i].to_string(),
                    y[i].to_string(),
                ));
            }
        }
        _ => {}
    }
    match (&a.floats, &b.floats) {
        (Some(x), Some(y)) if x.len() != y.len() => {
            out.push(("data.len".into(), x.len().to_string(), y.len().to_string()))
        }
        (Some(x), Some(y)) => {
            let bad: Vec<usize> = (0..x.len())
                .filter(|&i| !tol.close(x[i] as f64, y[i] as f64))
                .collect();
            if let Some(&i) = bad.first() {
                out.push((
                    format!("data[{i}] (floats; {} differ)", bad.len()),
                    x[i].to_string(),
                    y[i].to_string(),
                ));
            }
        }
        _ => {}
    }
    out
}

/// Per topic, the first message of each sequence number. A truncated
/// recording is an error: a diff against part of a run would report the
/// cut as missing frames.
fn by_seq(
    rec: &Recording,
    patterns: &[String],
) -> Result<BTreeMap<String, BTreeMap<u64, Vec<u8>>>, RecordingError> {
    let mut out: BTreeMap<String, BTreeMap<u64, Vec<u8>>> = BTreeMap::new();
    let cut = rec.for_each(|m| {
        if &*m.encoding == MESSAGE_ENCODING && crate::pattern::matches_any(patterns, &m.topic) {
            let d = decode(&m.topic, &m.data)?;
            let seq = d
                .fields
                .pointer("/stamp/frame_seq")
                .and_then(Value::as_u64)
                .unwrap_or(m.sequence as u64);
            // The first message of a frame is the stage's answer to it; a
            // later one with the same stamp is a repeat (the servo's stops).
            if seq > 0 {
                out.entry(m.topic.to_string())
                    .or_default()
                    .entry(seq)
                    .or_insert_with(|| m.data.into_owned());
            }
        }
        Ok(())
    })?;
    match cut {
        Some(t) => Err(RecordingError::Truncated(t)),
        None => Ok(out),
    }
}

/// Every difference between `golden` and `run` on the topics matching
/// `patterns`: missing or extra frames, and differing fields. Either file
/// damaged or truncated is an error naming it and the offset.
pub fn compare(
    golden: &Recording,
    run: &Recording,
    patterns: &[String],
    tol: Tolerance,
) -> Result<Vec<Mismatch>, RecordingError> {
    let (a, b) = (by_seq(golden, patterns)?, by_seq(run, patterns)?);
    let mut out = Vec::new();
    let topics: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    let empty = BTreeMap::new();
    for topic in topics {
        let (x, y) = (
            a.get(topic).unwrap_or(&empty),
            b.get(topic).unwrap_or(&empty),
        );
        for (seq, gold) in x {
            let Some(got) = y.get(seq) else {
                out.push(Mismatch {
                    topic: topic.clone(),
                    seq: *seq,
                    field: "(message)".into(),
                    expected: "a message".into(),
                    got: "none".into(),
                });
                continue;
            };
            for (field, expected, got) in
                compare_decoded(&decode(topic, gold)?, &decode(topic, got)?, tol)
            {
                out.push(Mismatch {
                    topic: topic.clone(),
                    seq: *seq,
                    field,
                    expected,
                    got,
                });
            }
        }
        for seq in y.keys().filter(|s| !x.contains_key(s)) {
            out.push(Mismatch {
                topic: topic.clone(),
                seq: *seq,
                field: "(message)".into(),
                expected: "none".into(),
                got: "a message".into(),
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_name_the_field_and_respect_the_tolerance() {
        let sub = |lambda: f32, seq: u64| Subgoal {
            stamp: Stamp::new(seq, 10),
            proximity_lambda_px: lambda,
            ..Default::default()
        };
        let enc = |s: &Subgoal| wire::encode_message(s).unwrap();
        let a = decode("nav/subgoal", &enc(&sub(50.0, 3))).unwrap();
        let near = decode("nav/subgoal", &enc(&sub(50.001, 3))).unwrap();
        let far = decode("nav/subgoal", &enc(&sub(51.0, 3))).unwrap();
        assert!(compare_decoded(&a, &near, Tolerance::default()).is_empty());
        let d = compare_decoded(&a, &far, Tolerance::default());
        assert_eq!(d.len(), 1, "{d:?}");
        assert_eq!(d[0].0, "proximity_lambda_px");
        // Integers are exact: a different sequence number is a difference.
        let other = decode("nav/subgoal", &enc(&sub(50.0, 4))).unwrap();
        assert_eq!(
            compare_decoded(&a, &other, Tolerance::default())[0].0,
            "stamp.frame_seq"
        );
    }

    #[test]
    fn image_bytes_are_exact_and_float_images_are_close() {
        let h = ImageHeader::packed(Stamp::new(1, 1), 0, 2, 1, PixelEncoding::MONO8);
        let a = decode(
            "camera/front/image",
            &wire::encode_slice(&h, &[1u8, 2]).unwrap(),
        )
        .unwrap();
        let b = decode(
            "camera/front/image",
            &wire::encode_slice(&h, &[1u8, 3]).unwrap(),
        )
        .unwrap();
        let d = compare_decoded(&a, &b, Tolerance::default());
        assert_eq!(d[0].0, "data[1] (bytes; 1 differ)");
        let hf = ImageHeader::packed(Stamp::new(1, 1), 0, 2, 1, PixelEncoding::F32);
        let f = |v: f32| {
            decode(
                "perception/front/heatmap",
                &wire::encode_slice(&hf, &[0.5f32, v]).unwrap(),
            )
            .unwrap()
        };
        assert!(compare_decoded(&f(0.25), &f(0.25 + 1e-6), Tolerance::default()).is_empty());
        assert_eq!(
            compare_decoded(&f(0.25), &f(0.3), Tolerance::default())[0].0,
            "data[1] (floats; 1 differ)"
        );
    }
}
