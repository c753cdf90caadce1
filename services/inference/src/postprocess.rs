//! Model outputs -> what the graph publishes: class id map + confidence,
//! navigability mask, affordance heatmap, far-field ensemble tensor. A tensor
//! with any NaN or infinite value is refused: its frame is dropped and counted,
//! never published.

use crate::model_config::{Activation, Layout, OutputKind, OutputSpec};

/// Why an output could not be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PostprocessError {
    #[error(
        "output '{name}' holds {count} non-finite values (first at index {first}); frame dropped"
    )]
    NonFinite {
        name: String,
        count: usize,
        first: usize,
    },
    #[error("output '{name}' has shape {got:?}, expected {expected}")]
    Shape {
        name: String,
        got: Vec<usize>,
        expected: String,
    },
}

/// Refuses a tensor with NaN or infinity.
pub fn check_finite(name: &str, data: &[f32]) -> Result<(), PostprocessError> {
    let mut bad = data.iter().enumerate().filter(|(_, v)| !v.is_finite());
    if let Some((first, _)) = bad.next() {
        return Err(PostprocessError::NonFinite {
            name: name.to_string(),
            count: 1 + bad.count(),
            first,
        });
    }
    Ok(())
}

/// Height, width and channel count of an image-like output `[1, C, H, W]` /
/// `[1, H, W, C]` (or without the batch dimension).
pub fn image_dims(
    spec: &OutputSpec,
    shape: &[usize],
) -> Result<(usize, usize, usize), PostprocessError> {
    let s: &[usize] = match shape {
        [1, rest @ ..] if rest.len() == 3 => rest,
        s if s.len() == 3 => s,
        [1, h, w] if spec.classes == 1 => return Ok((*h, *w, 1)),
        _ => {
            return Err(PostprocessError::Shape {
                name: spec.name.clone(),
                got: shape.to_vec(),
                expected: format!("[1, C, H, W] or [1, H, W, C] with C = {}", spec.classes),
            })
        }
    };
    let (h, w, c) = match spec.layout {
        Layout::Nchw => (s[1], s[2], s[0]),
        Layout::Nhwc => (s[0], s[1], s[2]),
    };
    if c != spec.classes {
        return Err(PostprocessError::Shape {
            name: spec.name.clone(),
            got: shape.to_vec(),
            expected: format!("{} channels ({:?} layout)", spec.classes, spec.layout),
        });
    }
    Ok((h, w, c))
}

/// Per-pixel class ids and the probability of the chosen class.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassMap {
    pub width: usize,
    pub height: usize,
    pub ids: Vec<u8>,
    pub confidence: Vec<f32>,
}

/// Argmax over classes, with softmax confidence for logits.
pub fn class_map(
    spec: &OutputSpec,
    shape: &[usize],
    data: &[f32],
) -> Result<ClassMap, PostprocessError> {
    check_finite(&spec.name, data)?;
    let (h, w, c) = image_dims(spec, shape)?;
    let plane = h * w;
    let mut ids = vec![0u8; plane];
    let logits = spec.kind == OutputKind::ClassLogits;
    let confidence = match spec.layout {
        // Plane by plane: contiguous, branch-light loops the compiler vectorises.
        Layout::Nchw => {
            let planes: Vec<&[f32]> = data.chunks_exact(plane).take(c).collect();
            let mut best = planes[0].to_vec();
            for (k, pk) in planes.iter().enumerate().skip(1) {
                for ((b, id), &v) in best.iter_mut().zip(ids.iter_mut()).zip(pk.iter()) {
                    if v > *b {
                        *b = v;
                        *id = k as u8;
                    }
                }
            }
            if !logits {
                best
            } else if c == 2 {
                // Softmax of two logits: the winner's probability is sigmoid(|a - b|).
                planes[0]
                    .iter()
                    .zip(planes[1])
                    .map(|(&a, &b)| 1.0 / (1.0 + (-(a - b).abs()).exp()))
                    .collect()
            } else {
                let mut sum = vec![0f32; plane];
                for pk in &planes {
                    for ((s, &v), &m) in sum.iter_mut().zip(pk.iter()).zip(&best) {
                        *s += (v - m).exp();
                    }
                }
                sum.iter().map(|s| 1.0 / s).collect()
            }
        }
        Layout::Nhwc => data
            .chunks_exact(c)
            .zip(ids.iter_mut())
            .map(|(px, id)| {
                let (k, &m) =
                    px.iter().enumerate().fold(
                        (0, &px[0]),
                        |acc, (k, v)| if *v > *acc.1 { (k, v) } else { acc },
                    );
                *id = k as u8;
                if logits {
                    1.0 / px.iter().map(|v| (v - m).exp()).sum::<f32>()
                } else {
                    m
                }
            })
            .collect(),
    };
    Ok(ClassMap {
        width: w,
        height: h,
        ids,
        confidence,
    })
}

fn activate(a: Activation, v: f32) -> f32 {
    match a {
        Activation::None => v,
        Activation::Sigmoid => 1.0 / (1.0 + (-v).exp()),
    }
}

/// A binary drivable mask (255 = drivable) from a 2-class or 1-channel output.
pub fn drivable_mask(
    spec: &OutputSpec,
    shape: &[usize],
    data: &[f32],
) -> Result<(usize, usize, Vec<u8>), PostprocessError> {
    check_finite(&spec.name, data)?;
    let (h, w, c) = image_dims(spec, shape)?;
    let plane = h * w;
    let mask = (0..plane)
        .map(|p| {
            let drivable = if c == 2 {
                let (a, b) = match spec.layout {
                    Layout::Nchw => (data[p], data[plane + p]),
                    Layout::Nhwc => (data[2 * p], data[2 * p + 1]),
                };
                b > a
            } else {
                activate(spec.activation, data[p]) > spec.threshold
            };
            if drivable {
                255
            } else {
                0
            }
        })
        .collect();
    Ok((w, h, mask))
}

/// An affordance heatmap in [0, 1].
pub fn heatmap(
    spec: &OutputSpec,
    shape: &[usize],
    data: &[f32],
) -> Result<(usize, usize, Vec<f32>), PostprocessError> {
    check_finite(&spec.name, data)?;
    let (h, w, _) = image_dims(spec, shape)?;
    Ok((
        w,
        h,
        data.iter()
            .map(|&v| activate(spec.activation, v).clamp(0.0, 1.0))
            .collect(),
    ))
}

/// HIP's per-trajectory log-likelihoods: `classes` finite values.
pub fn trajectory_log_q(
    spec: &OutputSpec,
    shape: &[usize],
    data: &[f32],
) -> Result<Vec<f32>, PostprocessError> {
    check_finite(&spec.name, data)?;
    if data.len() != spec.classes {
        return Err(PostprocessError::Shape {
            name: spec.name.clone(),
            got: shape.to_vec(),
            expected: format!("[1, {}] (classes = library size)", spec.classes),
        });
    }
    Ok(data.to_vec())
}

/// Checks a far-field ensemble output against its configured shape.
pub fn far_field(
    spec: &OutputSpec,
    shape: &[usize],
    data: &[f32],
) -> Result<[usize; 4], PostprocessError> {
    check_finite(&spec.name, data)?;
    let want = spec.ensemble_shape.unwrap_or_default();
    let got: Vec<usize> = match shape {
        [1, rest @ ..] if rest.len() == 4 => rest.to_vec(),
        s => s.to_vec(),
    };
    if got != want {
        return Err(PostprocessError::Shape {
            name: spec.name.clone(),
            got: shape.to_vec(),
            expected: format!("{want:?} (ensemble_shape)"),
        });
    }
    Ok(want)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(kind: OutputKind, classes: usize, layout: Layout) -> OutputSpec {
        OutputSpec {
            name: "o".into(),
            kind,
            layout,
            classes,
            threshold: 0.5,
            activation: Activation::None,
            ensemble_shape: None,
        }
    }

    #[test]
    fn class_map_argmax_and_softmax_confidence() {
        // 1x3 image, 2 classes, NCHW: class planes [0,5,1] and [1,0,1].
        let s = spec(OutputKind::ClassLogits, 2, Layout::Nchw);
        let m = class_map(&s, &[1, 2, 1, 3], &[0.0, 5.0, 1.0, 1.0, 0.0, 1.0]).unwrap();
        assert_eq!(m.ids, vec![1, 0, 0]);
        let e = 1.0 / (1.0 + (-1f32).exp());
        assert!((m.confidence[0] - e).abs() < 1e-6);
        assert!(
            (m.confidence[2] - 0.5).abs() < 1e-6,
            "a tie keeps class 0 at p = 0.5"
        );
        let nhwc = spec(OutputKind::ClassProbabilities, 2, Layout::Nhwc);
        let m = class_map(&nhwc, &[1, 1, 3, 2], &[0.2, 0.8, 0.9, 0.1, 0.4, 0.6]).unwrap();
        assert_eq!(m.ids, vec![1, 0, 1]);
        assert_eq!(m.confidence, vec![0.8, 0.9, 0.6]);
    }

    #[test]
    fn nan_and_wrong_channels_are_refused() {
        let s = spec(OutputKind::ClassLogits, 2, Layout::Nchw);
        let e = class_map(&s, &[1, 2, 1, 2], &[0.0, f32::NAN, 1.0, f32::INFINITY]).unwrap_err();
        assert_eq!(
            e,
            PostprocessError::NonFinite {
                name: "o".into(),
                count: 2,
                first: 1
            }
        );
        let e = class_map(&s, &[1, 3, 1, 1], &[0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("2 channels"), "{e}");
    }

    #[test]
    fn masks_from_two_classes_and_thresholds() {
        let two = spec(OutputKind::DrivableMask, 2, Layout::Nchw);
        let (_, _, m) = drivable_mask(&two, &[1, 2, 1, 2], &[1.0, 0.0, 0.0, 1.0]).unwrap();
        assert_eq!(m, vec![0, 255]);
        let mut one = spec(OutputKind::DrivableMask, 1, Layout::Nchw);
        one.activation = Activation::Sigmoid;
        let (_, _, m) = drivable_mask(&one, &[1, 1, 1, 2], &[-2.0, 2.0]).unwrap();
        assert_eq!(m, vec![0, 255]);
    }

    #[test]
    fn far_field_shape_must_match_config() {
        let mut s = spec(OutputKind::FarFieldEnsemble, 1, Layout::Nchw);
        s.ensemble_shape = Some([2, 3, 1, 2]);
        assert_eq!(
            far_field(&s, &[1, 2, 3, 1, 2], &[0.0; 12]).unwrap(),
            [2, 3, 1, 2]
        );
        assert!(far_field(&s, &[2, 3, 2, 1], &[0.0; 12]).is_err());
    }
}
