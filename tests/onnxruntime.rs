//! ONNX Runtime is loaded dynamically from the library `cargo xtask setup`
//! fetched (handed over in `ORT_DYLIB_PATH`), and runs a model: the sigmoid test
//! model that ships in the same wheel.

use std::path::PathBuf;

#[test]
fn runtime_from_the_cache_runs_a_model() {
    let lib = PathBuf::from(std::env::var("ORT_DYLIB_PATH").expect(
        "ORT_DYLIB_PATH is not set: run the tests with `cargo xtask test`, which fetches ONNX Runtime and sets it",
    ));
    let model = lib.parent().unwrap().join("sigmoid.onnx");
    let env = ort::init_from(&lib)
        .unwrap_or_else(|e| panic!("loading {}: {e}", lib.display()))
        .with_name("farsight-test")
        .build()
        .expect("ONNX Runtime environment");
    let mut session = ort::session::Session::builder(&env)
        .unwrap()
        .commit_from_file(&model)
        .unwrap_or_else(|e| panic!("loading {}: {e}", model.display()));
    let input_name = session.inputs()[0].name().to_string();
    let x: Vec<f32> = (0..60).map(|i| (i as f32 - 30.0) / 10.0).collect();
    let tensor = ort::value::Tensor::from_array(([3usize, 4, 5], x.clone())).unwrap();
    let outputs = session
        .run(ort::inputs![input_name.as_str() => tensor])
        .unwrap();
    let (shape, y) = outputs[0].try_extract_tensor::<f32>().unwrap();
    assert_eq!(shape.as_ref(), &[3, 4, 5]);
    for (xi, yi) in x.iter().zip(y) {
        assert!(
            (yi - 1.0 / (1.0 + (-xi).exp())).abs() < 1e-6,
            "sigmoid({xi}) = {yi}"
        );
    }
}
