//! The learned far field of `farsight bench fitam` (FITAM section V-A3's
//! learned row, issue 20 item 2): the simulator renders a rig of cameras
//! all round the robot, the shipped far-field model runs on each frame, and
//! bin projection's FITAM library turns each camera's slices into polar
//! bins, merged by certainty. FITAM's robots saw 360 degree panoramas; the
//! default rig is the simulator's four 120 degree cameras (front, left,
//! right, rear), which cover every one of the 32 heading bins.
//!
//! Everything comes from one graph file (`graphs/sim/fitam.toml` by
//! default), so the row measures what the graph would run: the inference
//! node's model config and the bin-projection node's `[fitam]` bins. Only
//! the camera count differs from the graph, which has one front camera.

use crate::graph::Graph;
use anyhow::{bail, Context, Result};
use farsight_bin_projection::fitam::{self, FitamBinsConfig};
use farsight_bin_projection::stage::BinProjectionConfig;
use farsight_costmap_fusion::swath::PolarGeometry;
use farsight_inference::model_config::{ModelConfig, OutputKind};
use farsight_inference::onnx::{OnnxModel, Timings};
use farsight_inference::stage::InferenceConfig;
use farsight_inference::Backend;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, PolarCell, Stamp};
use farsight_sim::fitam_protocol::FarFieldSource;
use farsight_sim::render::{Channels, Frame, Renderer};
use farsight_sim::run::named_camera;
use farsight_sim::world::World;
use std::path::{Path, PathBuf};

/// The simulator's frame size, as `farsight bench nav` renders for the
/// learned rows (the model resizes it to its input).
const FRAME_WIDTH: u32 = 640;
const FRAME_HEIGHT: u32 = 360;
/// How far the renderer marches a ray: past the far field's 100 m.
const RENDER_RANGE_M: f64 = 150.0;

/// What the learned row needs from a graph file, checked.
#[derive(Debug, Clone)]
pub struct LearnedGraph {
    pub model_config: PathBuf,
    /// The ONNX file the model config names (hashed into the protocol).
    pub model_file: PathBuf,
    pub bins: FitamBinsConfig,
}

impl LearnedGraph {
    /// The inference node's far-field model and the bin-projection node's
    /// FITAM bins of the graph at `path`; refuses a graph without them, a
    /// model without a far-field output, and bins that are not the
    /// protocol's `geometry`.
    pub fn load(path: &Path, geometry: &PolarGeometry) -> Result<Self> {
        let graph = Graph::load(path)?;
        let shown = path.display();
        let node = |stage: &str| {
            graph
                .nodes
                .iter()
                .find(|n| n.spec.stage == stage)
                .with_context(|| format!("{shown}: no {stage} node, so no learned far field"))
        };
        let inference = node("inference")?;
        let icfg: InferenceConfig = match &inference.config_text {
            Some(t) => farsight_stage::parse_config(t, &inference.config_origin)?,
            None => InferenceConfig::default(),
        };
        if icfg.backend != "onnx" {
            bail!(
                "{shown}: inference node {:?} has backend {:?}; the learned far field needs \"onnx\"",
                inference.spec.name,
                icfg.backend
            );
        }
        let model_config = inference.config_dir.join(&icfg.model_config);
        let model = ModelConfig::load(&model_config)?;
        if !model
            .outputs
            .iter()
            .any(|o| o.kind == OutputKind::FarFieldEnsemble)
        {
            bail!(
                "{}: no far_field_ensemble output, so not a FITAM far-field model",
                model_config.display()
            );
        }
        let projection = node("bin-projection")?;
        let pcfg: BinProjectionConfig = match &projection.config_text {
            Some(t) => farsight_stage::parse_config(t, &projection.config_origin)?,
            None => BinProjectionConfig::default(),
        };
        if pcfg.method != "fitam" {
            bail!(
                "{shown}: bin-projection node {:?} has method {:?}; the learned far field needs \"fitam\"",
                projection.spec.name,
                pcfg.method
            );
        }
        let bins = pcfg.fitam;
        let radial_match = bins.range_edges_m == geometry.range_edges_m;
        if bins.heading_bins != geometry.heading_bins || !radial_match {
            bail!(
                "{shown}: the bins ({} heading bins, radial edges {:?} m) are not the protocol's ({} heading bins, {:?} m)",
                bins.heading_bins,
                bins.range_edges_m,
                geometry.heading_bins,
                geometry.range_edges_m
            );
        }
        Ok(Self {
            model_file: model.model_path(),
            model_config,
            bins,
        })
    }
}

struct RigCamera {
    renderer: Renderer,
    /// Each model slice's heading bin, from this camera's mount; computed
    /// on the first frame, when the model's slice count is known.
    slice_bins: Option<Vec<Option<usize>>>,
}

/// The learned far field on a rig of simulated cameras: a
/// [`FarFieldSource`] for the protocol's agent.
pub struct LearnedRig {
    cameras: Vec<RigCamera>,
    backend: Backend,
    bins: FitamBinsConfig,
    frame: Frame,
    timings: Timings,
    /// Frames the model has seen.
    pub frames: u64,
}

impl LearnedRig {
    /// Loads the model (one ONNX Runtime session) and builds a renderer per
    /// camera of `rig` (the simulator's mounts: front, left, right, rear).
    pub fn new(graph: &LearnedGraph, rig: &[String]) -> Result<Self> {
        if rig.is_empty() {
            bail!("--rig: name at least one camera");
        }
        let model = OnnxModel::load(&ModelConfig::load(&graph.model_config)?)
            .with_context(|| format!("loading {}", graph.model_config.display()))?;
        let cameras = rig
            .iter()
            .map(|name| {
                let camera = named_camera(name, FRAME_WIDTH, FRAME_HEIGHT)?;
                let mut renderer = Renderer::new(&camera, RENDER_RANGE_M);
                // The trials run one per core already.
                renderer.threads = 1;
                Ok(RigCamera {
                    renderer,
                    slice_bins: None,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            cameras,
            backend: Backend::Onnx(Box::new(model)),
            bins: graph.bins.clone(),
            frame: Frame::default(),
            timings: Timings::default(),
            frames: 0,
        })
    }
}

impl FarFieldSource for LearnedRig {
    fn observe(&mut self, world: &World, pose: [f64; 3]) -> Result<Vec<PolarCell>> {
        let rgb_only = Channels {
            rgb: true,
            depth: false,
            class_ids: false,
        };
        let mut per_camera = Vec::with_capacity(self.cameras.len());
        for cam in self.cameras.iter_mut() {
            cam.renderer
                .render_channels(world, pose, &mut self.frame, rgb_only);
            let header = ImageHeader::packed(
                Stamp::new(self.frames, 0),
                cam.renderer.camera().id,
                self.frame.width as u32,
                self.frame.height as u32,
                PixelEncoding::RGB8,
            );
            let perception = self
                .backend
                .run(&header, &self.frame.rgb, None, &mut self.timings)
                .with_context(|| {
                    format!("far-field model on camera {:?}", cam.renderer.camera().name)
                })?;
            self.frames += 1;
            let Some((shape, logits)) = perception.far_field else {
                bail!("the far-field model gave no far_field_ensemble output");
            };
            let slice_bins = cam.slice_bins.get_or_insert_with(|| {
                fitam::slice_heading_bins(cam.renderer.camera(), shape[0], self.bins.heading_bins)
            });
            per_camera.push(fitam::polar_observation(
                &logits, shape, slice_bins, &self.bins,
            )?);
        }
        let views: Vec<&[PolarCell]> = per_camera.iter().map(|c| c.as_slice()).collect();
        Ok(fitam::merge_cameras(&views))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_rig_sees_every_heading_bin() {
        // The shipped model's 20 slices per camera, 32 heading bins.
        let mut seen = [false; 32];
        for name in ["front", "left", "right", "rear"] {
            let cam = named_camera(name, FRAME_WIDTH, FRAME_HEIGHT).unwrap();
            for b in fitam::slice_heading_bins(&cam, 20, 32)
                .into_iter()
                .flatten()
            {
                seen[b] = true;
            }
        }
        let missing: Vec<usize> = (0..32).filter(|&b| !seen[b]).collect();
        assert!(
            missing.is_empty(),
            "heading bins no camera sees: {missing:?}"
        );
        // One front camera, as the graph has, sees about a third.
        let front = named_camera("front", FRAME_WIDTH, FRAME_HEIGHT).unwrap();
        let mut one: Vec<usize> = fitam::slice_heading_bins(&front, 20, 32)
            .into_iter()
            .flatten()
            .collect();
        one.dedup();
        assert!((10..=12).contains(&one.len()), "{one:?}");
    }

    #[test]
    fn graphs_without_a_far_field_model_or_with_other_bins_are_refused() {
        let g = PolarGeometry::fitam_default();
        let repo = |f: &str| crate::graph::repo_file(f).unwrap();
        let e = LearnedGraph::load(&repo("graphs/sim/fitam-gt.toml"), &g).unwrap_err();
        assert!(e.to_string().contains("no inference node"), "{e}");
        let e = LearnedGraph::load(&repo("graphs/sim/lrn.toml"), &g).unwrap_err();
        assert!(e.to_string().contains("not a FITAM far-field model"), "{e}");
        let other = PolarGeometry {
            heading_bins: 16,
            ..g.clone()
        };
        let e = LearnedGraph::load(&repo("graphs/sim/fitam.toml"), &other).unwrap_err();
        assert!(
            e.to_string()
                .contains("not the protocol's (16 heading bins"),
            "{e}"
        );
        let ok = LearnedGraph::load(&repo("graphs/sim/fitam.toml"), &g).unwrap();
        assert!(ok.model_file.ends_with("sim-fitam/model.onnx"), "{ok:?}");
    }

    /// Needs ONNX Runtime (`ORT_DYLIB_PATH`), as the inference tests.
    #[test]
    fn the_shipped_model_on_the_rig_measures_every_heading_bin() {
        let g = PolarGeometry::fitam_default();
        let graph = LearnedGraph::load(
            &crate::graph::repo_file("graphs/sim/fitam.toml").unwrap(),
            &g,
        )
        .unwrap();
        let rig: Vec<String> = ["front", "left", "right", "rear"].map(String::from).into();
        let mut learned = LearnedRig::new(&graph, &rig).unwrap();
        let world = farsight_sim::scenario::random_world(1, 400).world;
        let cells = learned.observe(&world, [200.0, 200.0, 0.3]).unwrap();
        assert_eq!(cells.len(), 32 * 3);
        assert_eq!(learned.frames, 4);
        for (k, c) in cells.iter().enumerate() {
            assert!(
                c.cost_s_per_m.is_finite() && c.variance.is_finite(),
                "heading bin {} radial bin {} has no measurement: {c:?}",
                k / 3,
                k % 3
            );
            let speeds = &graph.bins.class_speeds_mps;
            assert!((c.cost_s_per_m as f64 - 1.0 / speeds[c.class_id as usize]).abs() < 1e-5);
        }
    }
}
