//! Several cameras through one ONNX Runtime session: a model whose batch
//! dimension is open runs a step's frames in one `session.run`, and each
//! frame's result is what it gets alone; a model exported for one frame runs
//! them one at a time in the same session. ONNX Runtime comes from
//! ORT_DYLIB_PATH (set by `cargo xtask test`).

use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{InferError, OnnxModel, Timings};
use farsight_inference::{Backend, FrameError, Perception};
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn load(config: &str) -> OnnxModel {
    OnnxModel::load(&ModelConfig::load(&repo().join(config)).unwrap()).unwrap()
}

/// Three different camera frames: the real ORFD frames, one per camera.
fn frames() -> Vec<(ImageHeader, Vec<u8>)> {
    farsight_tests::orfd_files("image_data")
        .iter()
        .take(3)
        .map(|p| farsight_imaging::decode_png(&std::fs::read(p).unwrap()).unwrap())
        .collect()
}

fn heatmaps(
    model: OnnxModel,
    frames: &[(&ImageHeader, &[u8])],
) -> Vec<Result<Perception, FrameError>> {
    Backend::Onnx(Box::new(model)).run_batch(frames, None, &mut Timings::default())
}

fn alone(config: &str, frame: (&ImageHeader, &[u8])) -> Vec<f32> {
    let mut b = Backend::Onnx(Box::new(load(config)));
    b.run(frame.0, frame.1, None, &mut Timings::default())
        .unwrap()
        .heatmap
        .unwrap()
}

fn close(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
}

const BATCHED: &str = "tests/fixtures/models/lrn-batch/model.toml";
const SINGLE: &str = "deploy/models/sim-lrn/model.toml";

#[test]
fn a_batch_gives_each_frame_what_it_gets_alone() {
    assert!(
        load(BATCHED).batches(),
        "the fixture's batch dimension is open"
    );
    assert!(
        !load(SINGLE).batches(),
        "the shipped model is exported for one frame"
    );
    let owned = frames();
    let inputs: Vec<(&ImageHeader, &[u8])> = owned.iter().map(|(h, d)| (h, d.as_slice())).collect();
    let want: Vec<Vec<f32>> = inputs.iter().map(|&f| alone(SINGLE, f)).collect();
    assert!(
        !close(&want[0], &want[1]),
        "the frames differ, so a mix-up would show"
    );
    for config in [BATCHED, SINGLE] {
        let got = heatmaps(load(config), &inputs);
        assert_eq!(got.len(), 3);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            let g = g.as_ref().unwrap();
            assert_eq!((g.width, g.height), (40, 24), "{config} frame {i}");
            assert!(close(g.heatmap.as_ref().unwrap(), w), "{config} frame {i}");
        }
    }
}

#[test]
fn a_bad_frame_leaves_the_batch_with_its_own_error() {
    let owned = frames();
    let mut short = owned[1].1.clone();
    short.truncate(100);
    let inputs = [
        (&owned[0].0, owned[0].1.as_slice()),
        (&owned[1].0, short.as_slice()),
        (&owned[2].0, owned[2].1.as_slice()),
    ];
    let got = heatmaps(load(BATCHED), &inputs);
    assert!(
        matches!(&got[1], Err(FrameError::Infer(InferError::Preprocess(_)))),
        "{:?}",
        got[1].as_ref().err()
    );
    for i in [0, 2] {
        let want = alone(SINGLE, inputs[i]);
        assert!(
            close(got[i].as_ref().unwrap().heatmap.as_ref().unwrap(), &want),
            "frame {i}"
        );
    }
    // A frame of another size in the same batch is resized like the rest.
    let small = ImageHeader::packed(Stamp::new(9, 9), 0, 4, 2, PixelEncoding::RGB8);
    let grey = vec![128u8; 4 * 2 * 3];
    let got = heatmaps(load(BATCHED), &[inputs[0], (&small, &grey)]);
    assert!(got.iter().all(Result::is_ok));
}
