//! The surface-normal backend on the real ORFD depth images: the dirt road ahead
//! is ground, the sky (no depth) and the tree line are not.

use farsight_inference::normals::{navigability, NormalsConfig};
use farsight_interfaces::camera::{Camera, CameraModel, Mount};

/// The ORFD camera (calib/cam_K); calib/cam_RT puts its optical axis about
/// 6.7 degrees below the lidar's horizontal.
fn orfd_camera() -> Camera {
    Camera::new(
        0,
        "front",
        CameraModel::pinhole(1280, 720, 1487.752825, 1471.063437, 625.011716, 376.483801),
        Mount::from_xyz_rpy_deg([0.0, 0.0, 1.5], [0.0, 6.7, 0.0]),
    )
}

use farsight_tests::navigable_fraction as fraction;

#[test]
fn orfd_road_ahead_is_ground() {
    let files = farsight_tests::orfd_files("dense_depth");
    let cfg = NormalsConfig::default();
    let cam = orfd_camera();
    for f in &files {
        let (h, raw) = farsight_imaging::decode_png(&std::fs::read(f).unwrap()).unwrap();
        let (w, hh) = (h.width as usize, h.height as usize);
        // Units do not change normal directions; metres only matter for display.
        let depth: Vec<f32> = raw
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]) as f32 * cfg.depth_scale_m)
            .collect();
        let nav = navigability(&depth, w, hh, &cam, &cfg);
        let road = fraction(&nav, w, hh, (0.25, 0.45), (0.80, 0.97));
        let sky = fraction(&nav, w, hh, (0.0, 1.0), (0.0, 0.12));
        let trees = fraction(&nav, w, hh, (0.70, 0.95), (0.15, 0.40));
        eprintln!(
            "{}: road {road:.2} sky {sky:.2} trees {trees:.2}",
            f.display()
        );
        if std::env::var_os("FARSIGHT_DEBUG_PNG").is_some() {
            let hdr = farsight_interfaces::msg::ImageHeader::packed(
                Default::default(),
                0,
                w as u32,
                hh as u32,
                farsight_interfaces::msg::PixelEncoding::MONO8,
            );
            std::fs::write(
                std::env::temp_dir().join(format!(
                    "normals-{}.png",
                    f.file_stem().unwrap().to_str().unwrap()
                )),
                farsight_imaging::encode_png(&hdr, &nav).unwrap(),
            )
            .unwrap();
        }
        assert!(
            road > 0.8,
            "{}: road ahead only {road:.2} ground",
            f.display()
        );
        assert!(sky < 0.01, "{}: sky {sky:.2} ground", f.display());
        assert!(trees < 0.2, "{}: tree line {trees:.2} ground", f.display());
    }
}
