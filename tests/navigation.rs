//! The image-space navigation chain on real data: TwinLiteNet's navigability
//! mask of the ORFD dirt road -> POVNav subgoal -> servo command.

use farsight_inference::class_table::ClassTableFile;
use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{OnnxModel, Timings};
use farsight_inference::Backend;
use farsight_subgoal_selection::povnav::{plan, safe_half_widths, Mode, PovnavConfig};
use farsight_tests::repo_root;
use farsight_velocity_servoing::{povnav_command, ServoConfig};

#[test]
fn orfd_road_goal_ahead_drives_forward_and_a_side_goal_turns_toward_it() {
    let config = ModelConfig::load(&repo_root().join("deploy/models/twinlitenet.toml")).unwrap();
    let table = ClassTableFile::open(&config.class_table_path().unwrap()).unwrap();
    let mut backend = Backend::Onnx(Box::new(OnnxModel::load(&config).unwrap()));
    let dir = repo_root().join("../shared/data/orfd/image_data");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    files.sort();
    // The ORFD camera (calib/cam_K) at the 640x360 model resolution, ~1.5 m up;
    // a 1 m wide robot with a 0.2 m margin.
    let half_widths = safe_half_widths(
        360,
        1487.75 / 2.0,
        1471.06 / 2.0,
        376.48 / 2.0,
        1.5,
        1.0,
        0.2,
    );
    let (pcfg, scfg) = (PovnavConfig::default(), ServoConfig::default());
    for f in &files {
        let (h, frame) = farsight_imaging::decode_png(&std::fs::read(f).unwrap()).unwrap();
        let p = backend
            .run(&h, &frame, Some(table.table()), &mut Timings::default())
            .unwrap();
        let nav = p.navigability.unwrap();
        let ahead = plan(&nav, p.width, p.height, 0.0, &half_widths, &pcfg);
        let (v, w) = povnav_command(ahead.proximity_px, ahead.alignment_rad, &scfg);
        eprintln!(
            "{}: ahead hog {:?} lambda {:.0} phi {:.2} mode {:?} -> v {v:.2} w {w:.2}",
            f.file_name().unwrap().to_string_lossy(),
            ahead.hog_px,
            ahead.proximity_px,
            ahead.alignment_rad,
            ahead.mode
        );
        assert_eq!(ahead.mode, Mode::Safe);
        assert!(v > 0.2, "drives forward along the road: v {v}");
        assert!(w.abs() < 0.5, "small turn rate with the goal ahead: {w}");
        for (deg, side) in [(60.0f64, 1.0), (-60.0, -1.0)] {
            let p = plan(
                &nav,
                p.width,
                p.height,
                deg.to_radians(),
                &half_widths,
                &pcfg,
            );
            let (_, w) = povnav_command(p.proximity_px, p.alignment_rad, &scfg);
            eprintln!(
                "  goal {deg}: hog {:?} phi {:.2} -> w {w:.2}",
                p.hog_px, p.alignment_rad
            );
            assert!(
                w * side > 0.1,
                "goal {deg} deg: turns toward its side (w {w})"
            );
        }
    }
}
