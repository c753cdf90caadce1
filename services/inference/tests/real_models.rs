//! The real pretrained models in ../shared/models on the real ORFD off-road
//! frames, through the library the stage and `farsight infer` share.
//! ONNX Runtime comes from ORT_DYLIB_PATH (set by `cargo xtask test`).

use farsight_inference::class_table::ClassTableFile;
use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{LoadError, OnnxModel, Timings};
use farsight_inference::{Backend, FrameError, Perception};
use farsight_interfaces::msg::ImageHeader;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn orfd_frames() -> Vec<(ImageHeader, Vec<u8>)> {
    farsight_tests::orfd_files("image_data")
        .iter()
        .map(|p| farsight_imaging::decode_png(&std::fs::read(p).unwrap()).unwrap())
        .collect()
}

fn run(config: &ModelConfig, header: &ImageHeader, frame: &[u8]) -> Result<Perception, FrameError> {
    let table = config
        .class_table_path()
        .map(|p| ClassTableFile::open(&p).unwrap());
    let mut backend = Backend::Onnx(Box::new(OnnxModel::load(config).unwrap()));
    backend.run(
        header,
        frame,
        table.as_ref().map(|t| t.table()),
        &mut Timings::default(),
    )
}

/// Fraction of navigable pixels in a box given as fractions of the image.
fn navigable_fraction(p: &Perception, x: (f64, f64), y: (f64, f64)) -> f64 {
    farsight_tests::navigable_fraction(p.navigability.as_ref().unwrap(), p.width, p.height, x, y)
}

#[test]
fn twinlitenet_marks_the_dirt_road_drivable_and_the_sky_not() {
    let config = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
    for (i, (h, frame)) in orfd_frames().iter().enumerate() {
        let p = run(&config, h, frame).unwrap();
        assert_eq!((p.width, p.height), (640, 360));
        // The dirt road in front of the vehicle: lower image, left of centre.
        let road = navigable_fraction(&p, (0.25, 0.45), (0.80, 0.97));
        // Sky: the top rows.
        let sky = navigable_fraction(&p, (0.0, 1.0), (0.0, 0.12));
        eprintln!("frame {i}: road {road:.2} sky {sky:.2}");
        assert!(
            road > 0.8,
            "frame {i}: only {road:.2} of the road ahead is drivable"
        );
        assert!(sky < 0.02, "frame {i}: {sky:.2} of the sky is drivable");
        let conf = &p.classes.as_ref().unwrap().confidence;
        assert!(
            conf.iter().all(|c| (0.5..=1.0).contains(c)),
            "argmax confidence of 2 classes is in [0.5, 1]"
        );
    }
}

#[test]
fn deeplabv3_nhwc_with_21_classes_runs() {
    let config = ModelConfig::load(&repo().join("deploy/models/deeplabv3-voc.toml")).unwrap();
    let (h, frame) = &orfd_frames()[0];
    let p = run(&config, h, frame).unwrap();
    assert_eq!((p.width, p.height), (257, 257));
    let classes = p.classes.unwrap();
    assert!(classes.ids.iter().all(|&c| c < 21));
    // No people or cars on this dirt road: VOC "background" dominates.
    let background =
        classes.ids.iter().filter(|&&c| c == 0).count() as f64 / classes.ids.len() as f64;
    assert!(background > 0.9, "background {background:.2}");
}

#[test]
fn a_model_whose_shape_does_not_match_its_config_is_refused_with_both_shapes() {
    let mut config = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
    config.input.width = 320;
    config.input.height = 180;
    let e = OnnxModel::load(&config).err().expect("must refuse");
    assert!(matches!(e, LoadError::ShapeMismatch { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("[1, 3, 360, 640]") && msg.contains("[1, 3, 180, 320]"),
        "{msg}"
    );

    let mut config = ModelConfig::load(&repo().join("deploy/models/deeplabv3-voc.toml")).unwrap();
    config.outputs[0].classes = 20;
    let msg = OnnxModel::load(&config)
        .err()
        .expect("must refuse")
        .to_string();
    assert!(
        msg.contains("[1, 257, 257, 21]") && msg.contains("[1, H, W, 20]"),
        "{msg}"
    );

    let mut config = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
    config.input.name = "image".into();
    let msg = OnnxModel::load(&config)
        .err()
        .expect("must refuse")
        .to_string();
    assert!(
        msg.contains("no input named 'image'") && msg.contains("\"images\""),
        "{msg}"
    );
}

/// This machine's ONNX Runtime is the CPU build and it has no GPU: asking
/// for CUDA or TensorRT must fail at load with the provider named, never
/// fall back to the CPU silently (issue 21, item 8).
#[test]
fn a_gpu_provider_this_runtime_lacks_is_refused_by_name() {
    use farsight_inference::model_config::ExecutionProvider;
    for (provider, name) in [
        (ExecutionProvider::Cuda, "cuda"),
        (ExecutionProvider::Tensorrt, "tensorrt"),
    ] {
        let mut config = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
        config.execution_provider = provider;
        let e = OnnxModel::load(&config).err().expect("must refuse");
        assert!(matches!(e, LoadError::Provider { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.starts_with(&format!("execution provider \"{name}\" is not available")),
            "{msg}"
        );
        assert!(msg.contains("execution_provider = \"cpu\""), "{msg}");
    }
}

#[test]
fn a_missing_model_file_is_a_clear_error() {
    let mut config = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
    config.model = "does-not-exist.onnx".into();
    let e = OnnxModel::load(&config).err().expect("must refuse");
    assert!(matches!(e, LoadError::MissingModel(_)), "{e}");
    assert!(
        e.to_string()
            .ends_with("does-not-exist.onnx does not exist"),
        "{e}"
    );
}

#[test]
fn non_finite_model_output_drops_the_frame() {
    // An input scale that overflows f32 drives the real network to inf/NaN.
    let mut config = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
    config.input.scale = 1e38;
    let (h, frame) = &orfd_frames()[0];
    match run(&config, h, frame) {
        Err(FrameError::Post(e)) => assert!(e.to_string().contains("non-finite"), "{e}"),
        other => panic!(
            "expected a non-finite output error, got {:?}",
            other.map(|p| p.width)
        ),
    }
}
