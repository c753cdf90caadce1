//! The bin-projection stage as a library type ([`ProjectionStage`]): each
//! camera's newest perception output becomes bins around the robot, one
//! output per input message.
//!
//! - `method = "lrn"`: LRN's angular bins (section III-B, Algorithm 2). An
//!   affordance heatmap (`perception/<camera>/heatmap`, f32) is summed per
//!   bearing bin through the camera's model and mount ([`crate::CameraBins`]),
//!   and the cameras' sums are combined, normalised and smoothed
//!   ([`crate::LrnBins`]) into `bins/angular`.
//! - `method = "fitam"`: FITAM's polar bins (section IV-C). A far-field
//!   ensemble output (`perception/<camera>/far_field`, a
//!   `[slices, radial, members, classes]` tensor) becomes polar cells in the
//!   heading bins its slices look into ([`crate::fitam`]); the cameras merge
//!   by certainty into `bins/polar`.
//!
//! Both share everything but the per-camera projection: the camera models
//! (`camera/<camera>/info`), and the cameras as one required input group on
//! capture time (farsight_stage::inputs). The stage is event-driven, so its
//! time is its inputs': a camera whose newest capture is more than
//! `input_deadline_s` older than the newest of any camera drops out of the
//! bins (and health says which), while the others go on. Each output carries
//! the newest capture among the cameras that made it.

use crate::fitam::{self, FitamBinsConfig};
use crate::stage::BinProjectionConfig;
use crate::{
    ground_range_table, traversability_depth_heatmap, BinGeometry, CameraBins, LrnBins, LrnInput,
    Projection,
};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::fixed::FixedVec;
use farsight_interfaces::message::{Image, Message, PolarBins, Tensor};
use farsight_interfaces::msg::{
    AngularBins, HealthState, PixelEncoding, PolarBinsHeader, PolarCell, Stamp, MAX_ANGULAR_BINS,
};
use farsight_interfaces::topics;
use farsight_stage::CameraModels;
use farsight_stage::{
    ClockSource, Freshness, HealthReport, Inbox, InputId, Need, Ports, Stage, StageEnv,
    StageInputs, StageKind, Step,
};
use std::time::Duration;

/// The bin-projection stage: one instance, its state between steps.
pub struct ProjectionStage {
    ports: Ports,
    /// Each camera's perception input (heatmap or far-field tensor).
    frames: Vec<usize>,
    output: usize,
    cameras: CameraModels,
    inputs: StageInputs,
    camera_in: Vec<InputId>,
    method: Method,
    /// With `join_cameras_by_frame`: each camera's newest frame number
    /// taken in, and the frame last answered.
    join: Option<FrameJoin>,
}

/// The cameras' frames joined by number (`join_cameras_by_frame`).
struct FrameJoin {
    newest: Vec<Option<u64>>,
    answered: u64,
}

impl FrameJoin {
    /// Camera `i` took in frame `seq`; `true` when every camera has now
    /// taken in the newest frame any camera has, and it is not answered yet.
    fn complete(&mut self, i: usize, seq: u64) -> bool {
        self.newest[i] = Some(self.newest[i].map_or(seq, |s| s.max(seq)));
        let Some(newest) = self.newest.iter().flatten().max().copied() else {
            return false;
        };
        let all = self.newest.iter().all(|s| *s == Some(newest));
        if all && newest > self.answered {
            self.answered = newest;
            return true;
        }
        false
    }
}

/// What differs between the methods: the per-camera projection, its cached
/// tables, each camera's latest projection, and how they combine.
enum Method {
    Lrn(Lrn),
    Fitam(Fitam),
}

struct Lrn {
    geometry: BinGeometry,
    pixel_threshold: f32,
    input: LrnInput,
    range_cap_m: f64,
    /// Per camera: pixel -> bin, for the model and heatmap size it was built
    /// for (un-projecting a fisheye is iterative: not once per frame).
    tables: Vec<Option<CameraBins>>,
    /// With [`LrnInput::Navigability`], per camera: its size and each
    /// pixel's flat-ground range.
    ranges: Vec<Option<(usize, usize, Vec<f32>)>>,
    /// The navigability's heatmap, reused frame to frame.
    scratch: Vec<f32>,
    /// Each camera's latest projection; a camera that stops sending drops
    /// out instead of holding its bins forever.
    latest: Vec<Option<Projection>>,
    bins: LrnBins,
}

struct Fitam {
    cfg: FitamBinsConfig,
    header: PolarBinsHeader,
    /// Per camera: slice -> heading bin, for a slice count.
    slice_bins: Vec<Option<(usize, Vec<Option<usize>>)>>,
    latest: Vec<Option<Vec<PolarCell>>>,
}

impl StageKind for ProjectionStage {
    const KIND: &'static str = "bin-projection";
    type Config = BinProjectionConfig;

    fn new(config: BinProjectionConfig, _env: &StageEnv) -> anyhow::Result<Self> {
        let fitam = config.method == "fitam";
        let mut ports = Ports {
            // Outputs answer inputs; the tick only keeps health (and
            // systemd's watchdog) going while no camera sends.
            tick: Some(Duration::from_millis(200)),
            health_rate_hz: config.health_rate_hz,
            ..Ports::default()
        };
        let frames = config
            .cameras
            .iter()
            .map(|c| ports.waking_input(config.perception_topic(c)))
            .collect();
        let cameras = CameraModels::declare(&mut ports, &config.cameras);
        let n = config.cameras.len();
        let (output, method) = if fitam {
            let cfg = config.fitam.clone();
            let radial = cfg.range_edges_m.len() - 1;
            // The bins' shared memory is sized up front: one cell per
            // (heading, radial) bin.
            let max_bytes = cfg.heading_bins * radial * std::mem::size_of::<PolarCell>();
            let output = ports.slice_output(topics::polar_bins().name(), max_bytes);
            let header = PolarBinsHeader {
                stamp: Stamp::default(),
                heading_bins: cfg.heading_bins as u32,
                first_heading_start_rad: -std::f32::consts::PI,
                heading_width_rad: std::f32::consts::TAU / cfg.heading_bins as f32,
                range_edges_m: FixedVec::from_slice(
                    &cfg.range_edges_m
                        .iter()
                        .map(|&e| e as f32)
                        .collect::<Vec<_>>(),
                )
                .unwrap_or_default(),
            };
            let method = Method::Fitam(Fitam {
                cfg,
                header,
                slice_bins: vec![None; n],
                latest: vec![None; n],
            });
            (output, method)
        } else {
            let geometry = BinGeometry::from_width_deg(config.bins.bin_width_deg);
            let output = ports.output(topics::angular_bins().name());
            let method = Method::Lrn(Lrn {
                geometry,
                pixel_threshold: config.bins.pixel_threshold(),
                input: config.bins.input,
                range_cap_m: config.bins.range_cap_m,
                tables: vec![None; n],
                ranges: vec![None; n],
                scratch: Vec::new(),
                latest: vec![None; n],
                bins: LrnBins::new(geometry, config.bins),
            });
            (output, method)
        };
        // The cameras as one required group: the bins go on while any
        // camera sends, and carry the newest capture among them.
        let mut inputs = StageInputs::new(config.input_deadline_s);
        let camera_in = config
            .cameras
            .iter()
            .map(|c| inputs.add_to("cameras", c, Need::Required))
            .collect();
        let join = config.join_cameras_by_frame.then(|| FrameJoin {
            newest: vec![None; n],
            answered: 0,
        });
        Ok(Self {
            ports,
            frames,
            output,
            cameras,
            inputs,
            camera_in,
            method,
            join,
        })
    }
}

impl Stage for ProjectionStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        // Models first: a frame is projected with the model that came with it.
        let health = &mut *step.health;
        let changed = self.cameras.refresh(step.inbox, |name, e| {
            health.dropped(&format_args!("camera info {name}: {e}"))
        });
        for i in changed {
            self.method.forget_tables(i);
        }
        // Every input message gets its output, in camera order; a frame
        // arriving with another camera's wake is not left behind.
        for i in 0..self.frames.len() {
            let camera = self.cameras.get(i);
            let name = self.cameras.name(i);
            let Some(observed) = self
                .method
                .observe(i, step.inbox, self.frames[i], camera, name)
            else {
                continue;
            };
            step.health.input();
            let frame_stamp = match observed {
                Ok(stamp) => stamp,
                Err(why) => {
                    step.health.dropped(&why);
                    continue;
                }
            };
            self.inputs.consumed(self.camera_in[i], frame_stamp);
            if let Some(join) = &mut self.join {
                if !join.complete(i, frame_stamp.frame_seq) {
                    continue;
                }
            }
            let fresh = fresh_cameras(&self.inputs, &self.camera_in, step.wall_ns, step.health);
            let stamp = self.inputs.output_stamp().unwrap_or(frame_stamp);
            step.out
                .send(self.output, self.method.output(&fresh, stamp));
            step.health.output(stamp, step.wall_ns);
        }
        // Health is judged on the wall clock (step.now_ns stays wall_ns):
        // its latency is capture to output, in real time.
    }
}

/// Which cameras are fresh: within the deadline of the newest capture of
/// any camera (an event-driven stage: time is its inputs'), with the
/// stage's health saying which ones dropped out.
fn fresh_cameras(
    inputs: &StageInputs,
    ids: &[InputId],
    wall_ns: u64,
    health: &mut HealthReport,
) -> Vec<bool> {
    let now = inputs.now_at(ClockSource::Stamps, wall_ns);
    match inputs.check(now) {
        Freshness::Fresh => health.set(HealthState::OK, ""),
        other => health.set(HealthState::DEGRADED, other.reason()),
    }
    ids.iter().map(|&id| inputs.is_fresh(id, now)).collect()
}

impl Method {
    /// Camera `i`'s model changed: its tables no longer fit.
    fn forget_tables(&mut self, i: usize) {
        match self {
            Self::Lrn(m) => {
                m.tables[i] = None;
                m.ranges[i] = None;
            }
            Self::Fitam(m) => m.slice_bins[i] = None,
        }
    }

    /// Takes camera `i`'s frame from `port` and projects it: `None` with no
    /// frame; the frame's stamp, or why it was dropped.
    fn observe(
        &mut self,
        i: usize,
        inbox: &mut Inbox,
        port: usize,
        camera: Option<&Camera>,
        name: &str,
    ) -> Option<Result<Stamp, String>> {
        let no_model = || format!("no camera model yet for {name}");
        match self {
            Self::Lrn(m) => {
                let heatmap = inbox.take::<Image>(port)?;
                Some(m.observe(i, &heatmap, camera.ok_or_else(no_model)))
            }
            Self::Fitam(m) => {
                let tensor = inbox.take::<Tensor>(port)?;
                Some(m.observe(i, &tensor, camera.ok_or_else(no_model), name))
            }
        }
    }

    /// The bins of the fresh cameras' latest projections, stamped `stamp`.
    fn output(&mut self, fresh: &[bool], stamp: Stamp) -> Message {
        match self {
            Self::Lrn(m) => m.output(fresh, stamp).into(),
            Self::Fitam(m) => m.output(fresh, stamp).into(),
        }
    }
}

/// The latest entries of the cameras marked fresh.
fn fresh_latest<'a, T>(latest: &'a [Option<T>], fresh: &'a [bool]) -> impl Iterator<Item = &'a T> {
    latest
        .iter()
        .zip(fresh)
        .filter(|(_, &f)| f)
        .filter_map(|(l, _)| l.as_ref())
}

impl Lrn {
    fn observe(
        &mut self,
        i: usize,
        heatmap: &Image,
        camera: Result<&Camera, String>,
    ) -> Result<Stamp, String> {
        let h = heatmap.header;
        h.validate(heatmap.data.len()).map_err(|e| e.to_string())?;
        let want = match self.input {
            LrnInput::Heatmap => PixelEncoding::F32,
            LrnInput::Navigability => PixelEncoding::MONO8,
        };
        if h.encoding != want {
            return Err(format!(
                "{} must be {want}, got {}",
                match self.input {
                    LrnInput::Heatmap => "heatmap",
                    LrnInput::Navigability => "navigability",
                },
                h.encoding
            ));
        }
        let cam = camera?;
        let (w, hh) = (h.width as usize, h.height as usize);
        let table = match &mut self.tables[i] {
            Some(t) if (t.width, t.height) == (w, hh) => t,
            slot => slot.insert(CameraBins::new(cam, w, hh, &self.geometry)),
        };
        if self.input == LrnInput::Navigability {
            let (_, _, range_m) = match &mut self.ranges[i] {
                Some(r) if (r.0, r.1) == (w, hh) => r,
                slot => slot.insert((w, hh, ground_range_table(cam, w, hh, self.range_cap_m))),
            };
            traversability_depth_heatmap(&heatmap.data, range_m, &mut self.scratch);
            self.latest[i] = Some(table.project(&self.scratch, self.pixel_threshold));
            return Ok(h.stamp);
        }
        // Read the heatmap in place; copy only if the bytes are not
        // f32-aligned (an owned byte buffer promises no alignment).
        let copied: Vec<f32>;
        let values: &[f32] = match bytemuck::try_cast_slice(&heatmap.data) {
            Ok(v) => v,
            Err(_) => {
                copied = heatmap
                    .data
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect();
                &copied
            }
        };
        self.latest[i] = Some(table.project(values, self.pixel_threshold));
        Ok(h.stamp)
    }

    fn output(&mut self, fresh: &[bool], stamp: Stamp) -> AngularBins {
        let fresh: Vec<Projection> = fresh_latest(&self.latest, fresh).cloned().collect();
        let scores = self.bins.update(&fresh);
        let k = self.geometry.count.min(MAX_ANGULAR_BINS);
        AngularBins {
            stamp,
            first_bin_start_rad: self.geometry.start_rad() as f32,
            bin_width_rad: self.geometry.width_rad() as f32,
            scores: FixedVec::from_slice(
                &scores.scores[..k]
                    .iter()
                    .map(|&v| v as f32)
                    .collect::<Vec<_>>(),
            )
            .unwrap_or_default(),
            observed: FixedVec::from_slice(
                &scores.observed[..k]
                    .iter()
                    .map(|&o| o as u8)
                    .collect::<Vec<_>>(),
            )
            .unwrap_or_default(),
        }
    }
}

impl Fitam {
    fn observe(
        &mut self,
        i: usize,
        tensor: &Tensor,
        camera: Result<&Camera, String>,
        name: &str,
    ) -> Result<Stamp, String> {
        let h = tensor.header;
        let shape = h.shape();
        if shape.len() != 4 || h.element_count() != tensor.data.len() {
            return Err(format!(
                "far-field tensor of shape {shape:?} with {} values; want [slices, radial, members, classes]",
                tensor.data.len()
            ));
        }
        let shape = [0, 1, 2, 3].map(|k| shape[k] as usize);
        let cam = camera?;
        let heading_bins = self.cfg.heading_bins;
        let (_, bins) = match &mut self.slice_bins[i] {
            Some(b) if b.0 == shape[0] => b,
            slot => slot.insert((
                shape[0],
                fitam::slice_heading_bins(cam, shape[0], heading_bins),
            )),
        };
        let cells = fitam::polar_observation(&tensor.data, shape, bins, &self.cfg)
            .map_err(|e| format!("{name}: {e}"))?;
        self.latest[i] = Some(cells);
        Ok(h.stamp)
    }

    fn output(&mut self, fresh: &[bool], stamp: Stamp) -> PolarBins {
        let fresh: Vec<&[PolarCell]> = fresh_latest(&self.latest, fresh)
            .map(Vec::as_slice)
            .collect();
        // (Functional update syntax here trips a rustc 1.95 MIR bug with the
        // const-generic FixedVec inside the header.)
        let mut header = self.header;
        header.stamp = stamp;
        PolarBins {
            header,
            data: fitam::merge_cameras(&fresh),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};
    use farsight_interfaces::msg::{CameraInfo, ImageHeader, TensorHeader};
    use farsight_stage::runtime::Harness;
    use farsight_stage::Wake;

    const S: u64 = 1_000_000_000;
    const W: usize = 64;
    const H: usize = 32;

    fn stage(toml: &str) -> Harness<ProjectionStage> {
        let config: BinProjectionConfig = farsight_stage::parse_config(toml, "test").unwrap();
        let env = StageEnv {
            instance: "bins".into(),
            config_dir: ".".into(),
        };
        Harness::new(ProjectionStage::new(config, &env).unwrap())
    }

    fn stamp(seq: u64, t_ns: u64) -> Stamp {
        Stamp::new(seq, t_ns)
    }

    /// A 64x32 pinhole camera with a 90 degree field of view, facing
    /// `yaw_deg` (0 = ahead, 180 = behind).
    fn camera(id: u32, name: &str, yaw_deg: f64) -> Camera {
        Camera::new(
            id,
            name,
            CameraModel::pinhole(W as u32, H as u32, 32.0, 32.0, 31.5, 15.5),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0, 0.0, yaw_deg]),
        )
    }

    fn info(cam: &Camera) -> CameraInfo {
        cam.to_info(Stamp::default())
    }

    fn heatmap(cam: &Camera, at: Stamp, value: f32) -> Image {
        let values = vec![value; W * H];
        Image {
            header: ImageHeader::packed(at, cam.id, W as u32, H as u32, PixelEncoding::F32),
            data: bytemuck::cast_slice(&values).to_vec(),
        }
    }

    fn angular(out: Vec<(String, Message)>) -> Vec<AngularBins> {
        out.into_iter()
            .map(|(topic, m)| {
                assert_eq!(topic, "bins/angular");
                AngularBins::try_from(m).unwrap()
            })
            .collect()
    }

    /// Bin index of a bearing for the stage's bins.
    fn bin_of(b: &AngularBins, deg: f64) -> usize {
        let a = (deg.to_radians() - b.first_bin_start_rad as f64).rem_euclid(std::f64::consts::TAU);
        (a / b.bin_width_rad as f64) as usize
    }

    #[test]
    fn a_fresh_heatmap_gives_one_set_of_bins_carrying_its_stamp() {
        let mut h = stage("cameras = [\"front\"]\n[bins]\nalpha = 1.0\nh_thresh = 0.5\n");
        let front = camera(0, "front", 0.0);
        let wake = h.wake_on("perception/front/heatmap");
        h.put("camera/front/info", info(&front));
        h.put(
            "perception/front/heatmap",
            heatmap(&front, stamp(7, 10 * S), 1.0),
        );
        let bins = angular(h.step(wake, 10 * S + S / 10));
        assert_eq!(bins.len(), 1);
        assert_eq!(bins[0].stamp, stamp(7, 10 * S));
        let o = bins[0].observed.as_slice();
        assert_eq!(
            (o[bin_of(&bins[0], 0.0)], o[bin_of(&bins[0], 179.0)]),
            (1, 0)
        );
        let total: f32 = bins[0].scores.as_slice().iter().sum();
        assert!((total - 1.0).abs() < 1e-4, "normalised: {total}");
        assert_eq!(h.health.state(), HealthState::OK);
        assert_eq!(h.health.report().messages_in, 1);
        assert_eq!(h.health.report().messages_out, 1);
        // The model stays: the next heatmap needs no new info, and a tick
        // with nothing new sends nothing.
        h.put(
            "perception/front/heatmap",
            heatmap(&front, stamp(8, 11 * S), 1.0),
        );
        assert_eq!(angular(h.step(wake, 11 * S))[0].stamp.frame_seq, 8);
        assert!(h.step(Wake::Tick, 11 * S + S / 5).is_empty());
    }

    #[test]
    fn navigability_times_range_makes_the_traversability_baseline_bins() {
        // 1 m up, 10 degrees down, 90 degree field of view: the horizon is
        // above the image centre, the lower rows are near ground.
        let front = Camera::new(
            0,
            "front",
            CameraModel::pinhole(W as u32, H as u32, 32.0, 32.0, 31.5, 15.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 10.0, 0.0]),
        );
        let mut h = stage("cameras = [\"front\"]\n[bins]\nalpha = 1.0\nh_thresh = 0.0\ninput = \"navigability\"\n");
        let wake = h.wake_on("perception/front/navigability");
        h.put("camera/front/info", info(&front));
        // Navigable: the left half's bottom row only (near), and the right
        // half's whole ground (out to the far rows).
        let mut nav = vec![0u8; W * H];
        for v in 0..H {
            for u in 0..W {
                if v == H - 1 || u >= W / 2 {
                    nav[v * W + u] = 255;
                }
            }
        }
        let image = |data: Vec<u8>, enc| Image {
            header: ImageHeader::packed(stamp(3, 10 * S), 0, W as u32, H as u32, enc),
            data,
        };
        h.put(
            "perception/front/navigability",
            image(nav, PixelEncoding::MONO8),
        );
        let bins = angular(h.step(wake, 10 * S));
        let sc = bins[0].scores.as_slice();
        // Left of centre is +bearing (counter-clockwise).
        let (left, right) = (sc[bin_of(&bins[0], 20.0)], sc[bin_of(&bins[0], -20.0)]);
        assert!(
            right > 5.0 * left && left > 0.0,
            "far beats near: {left} vs {right}"
        );
        // A heatmap where navigability was configured is dropped by name.
        h.put(
            "perception/front/navigability",
            image(vec![0; W * H * 4], PixelEncoding::F32),
        );
        assert!(h.step(wake, 11 * S).is_empty());
        assert_eq!(h.health.report().dropped, 1);
    }

    #[test]
    fn joined_by_frame_the_order_cameras_answer_in_does_not_change_the_bins() {
        let (front, rear) = (camera(0, "front", 0.0), camera(1, "rear", 180.0));
        // Two frames; each camera's heatmap put in its own step, in the
        // given order per frame. Returns every output.
        let run = |join: bool, orders: [[usize; 2]; 2]| {
            let mut h = stage(&format!(
                "cameras = [\"front\", \"rear\"]\njoin_cameras_by_frame = {join}\n\
                 [bins]\nalpha = 0.5\nh_thresh = 0.5\nthreshold_on = \"bins\"\n"
            ));
            h.put("camera/front/info", info(&front));
            h.put("camera/rear/info", info(&rear));
            let mut out = Vec::new();
            for (k, order) in orders.iter().enumerate() {
                let seq = k as u64 + 1;
                for &c in order {
                    let (cam, topic) = [
                        (&front, "perception/front/heatmap"),
                        (&rear, "perception/rear/heatmap"),
                    ][c];
                    let value = [[1.0, 0.2], [0.3, 0.9]][k][c];
                    h.put(topic, heatmap(cam, stamp(seq, seq * S), value));
                    out.extend(angular(h.step(h.wake_on(topic), seq * S)));
                }
            }
            out
        };
        let a = run(true, [[0, 1], [1, 0]]);
        let b = run(true, [[1, 0], [0, 1]]);
        assert_eq!(a.len(), 2, "one output per frame");
        assert_eq!(
            a.iter().map(|b| b.stamp.frame_seq).collect::<Vec<_>>(),
            [1, 2]
        );
        assert_eq!(a, b);
        // One output per input: the order shows in the smoothed bins.
        let a = run(false, [[0, 1], [1, 0]]);
        let b = run(false, [[1, 0], [0, 1]]);
        assert_eq!(a.len(), 4);
        assert_ne!(a.last(), b.last());
    }

    #[test]
    fn a_stale_camera_drops_out_of_the_bins_and_health_names_it() {
        let mut h = stage("cameras = [\"front\", \"rear\"]\n[bins]\nalpha = 1.0\nh_thresh = 0.5\n");
        let (front, rear) = (camera(0, "front", 0.0), camera(1, "rear", 180.0));
        h.put("camera/front/info", info(&front));
        h.put("camera/rear/info", info(&rear));
        h.put(
            "perception/rear/heatmap",
            heatmap(&rear, stamp(1, 10 * S), 1.0),
        );
        let wake = h.wake_on("perception/rear/heatmap");
        let b = angular(h.step(wake, 10 * S));
        assert_eq!(b[0].observed.as_slice()[bin_of(&b[0], 179.0)], 1);
        assert_eq!(h.health.state(), HealthState::DEGRADED, "no front yet");
        assert_eq!(h.health.report().reason.as_str(), "no front yet");
        // The front camera 2.5 s of capture time later: the rear one (1 s
        // deadline) drops out, but the bins keep coming.
        let wake = h.wake_on("perception/front/heatmap");
        h.put(
            "perception/front/heatmap",
            heatmap(&front, stamp(2, 12 * S + S / 2), 1.0),
        );
        let b = angular(h.step(wake, 12 * S + S / 2));
        assert_eq!(b.len(), 1);
        assert_eq!(b[0].stamp, stamp(2, 12 * S + S / 2));
        let o = b[0].observed.as_slice();
        assert_eq!((o[bin_of(&b[0], 0.0)], o[bin_of(&b[0], 179.0)]), (1, 0));
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert_eq!(
            h.health.report().reason.as_str(),
            "rear is 2.50 s old (deadline 1 s)"
        );
        // The rear camera is back, its frame a little older than the front's:
        // the bins carry the newest capture among the cameras.
        let wake = h.wake_on("perception/rear/heatmap");
        h.put(
            "perception/rear/heatmap",
            heatmap(&rear, stamp(3, 12 * S + 4 * S / 10), 1.0),
        );
        let b = angular(h.step(wake, 12 * S + S / 2));
        assert_eq!(b[0].stamp, stamp(2, 12 * S + S / 2));
        assert_eq!(b[0].observed.as_slice()[bin_of(&b[0], 179.0)], 1);
        assert_eq!(h.health.state(), HealthState::OK);
    }

    #[test]
    fn bad_heatmaps_and_infos_are_counted_drops_not_outputs() {
        let mut h = stage("cameras = [\"front\"]\n");
        let front = camera(0, "front", 0.0);
        let wake = h.wake_on("perception/front/heatmap");
        // No model yet.
        h.put(
            "perception/front/heatmap",
            heatmap(&front, stamp(1, S), 1.0),
        );
        assert!(h.step(wake, S).is_empty());
        assert_eq!(h.health.report().dropped, 1);
        // A broken model: counted, and still no model.
        let mut broken = info(&front);
        broken.lens = farsight_interfaces::msg::LensModel(99);
        h.put("camera/front/info", broken);
        h.put(
            "perception/front/heatmap",
            heatmap(&front, stamp(2, 2 * S), 1.0),
        );
        assert!(h.step(wake, 2 * S).is_empty());
        assert_eq!(h.health.report().dropped, 3, "the info and the heatmap");
        // A mono8 heatmap, and one whose header promises more than it holds.
        h.put("camera/front/info", info(&front));
        let mono = Image {
            header: ImageHeader::packed(
                stamp(3, 3 * S),
                0,
                W as u32,
                H as u32,
                PixelEncoding::MONO8,
            ),
            data: vec![255; W * H],
        };
        h.put("perception/front/heatmap", mono);
        assert!(h.step(wake, 3 * S).is_empty());
        let mut short = heatmap(&front, stamp(4, 4 * S), 1.0);
        short.data.truncate(100);
        h.put("perception/front/heatmap", short);
        assert!(h.step(wake, 4 * S).is_empty());
        assert_eq!(h.health.report().dropped, 5);
        assert_eq!(h.health.report().messages_out, 0);
        // The model survived the broken info before it: a good heatmap goes out.
        h.put(
            "perception/front/heatmap",
            heatmap(&front, stamp(5, 5 * S), 1.0),
        );
        let mut broken = info(&front);
        broken.lens = farsight_interfaces::msg::LensModel(99);
        h.put("camera/front/info", broken);
        assert_eq!(angular(h.step(wake, 5 * S))[0].stamp.frame_seq, 5);
        assert_eq!(h.health.report().dropped, 6);
    }

    /// A far-field tensor `[slices, 3 radial, 1 member, 3 classes]`, every
    /// slice sure of class 2.
    fn far_field(cam: &Camera, at: Stamp, slices: u32, radial: u32) -> Tensor {
        let per = (radial * 3) as usize;
        let data: Vec<f32> = (0..slices as usize * per)
            .map(|k| if k % 3 == 2 { 9.0 } else { 0.0 })
            .collect();
        Tensor {
            header: TensorHeader::new(at, cam.id, &[slices, radial, 1, 3]),
            data,
        }
    }

    fn polar(out: Vec<(String, Message)>) -> Vec<PolarBins> {
        out.into_iter()
            .map(|(topic, m)| {
                assert_eq!(topic, "bins/polar");
                PolarBins::try_from(m).unwrap()
            })
            .collect()
    }

    #[test]
    fn a_fresh_far_field_gives_polar_bins_carrying_its_stamp() {
        let mut h = stage("method = \"fitam\"\ncameras = [\"front\"]\n");
        let front = camera(0, "front", 0.0);
        let wake = h.wake_on("perception/front/far_field");
        h.put("camera/front/info", info(&front));
        h.put(
            "perception/front/far_field",
            far_field(&front, stamp(3, 10 * S), 8, 3),
        );
        let bins = polar(h.step(wake, 10 * S));
        assert_eq!(bins.len(), 1);
        assert_eq!(bins[0].header.stamp, stamp(3, 10 * S));
        assert_eq!(bins[0].header.heading_bins, 32);
        assert_eq!(bins[0].data.len(), 32 * 3);
        // Ahead is measured (class 2), behind is not.
        let ahead = bins[0].data[16 * 3];
        assert_eq!(ahead.class_id, 2);
        assert!(bins[0].data[0].variance.is_infinite());
        assert_eq!(h.health.state(), HealthState::OK);
    }

    #[test]
    fn a_mismatched_far_field_is_a_counted_drop_naming_the_camera() {
        let mut h = stage("method = \"fitam\"\ncameras = [\"front\"]\n");
        let front = camera(0, "front", 0.0);
        let wake = h.wake_on("perception/front/far_field");
        h.put("camera/front/info", info(&front));
        // Two radial bins where range_edges_m describes three.
        h.put(
            "perception/front/far_field",
            far_field(&front, stamp(1, S), 8, 2),
        );
        assert!(h.step(wake, S).is_empty());
        // Fewer values than the shape says.
        let mut short = far_field(&front, stamp(2, 2 * S), 8, 3);
        short.data.pop();
        h.put("perception/front/far_field", short);
        assert!(h.step(wake, 2 * S).is_empty());
        // Not rank 4.
        let flat = Tensor {
            header: TensorHeader::new(stamp(3, 3 * S), 0, &[9]),
            data: vec![0.0; 9],
        };
        h.put("perception/front/far_field", flat);
        assert!(h.step(wake, 3 * S).is_empty());
        assert_eq!(h.health.report().dropped, 3);
        assert_eq!(h.health.report().messages_in, 3);
        // Still running.
        h.put(
            "perception/front/far_field",
            far_field(&front, stamp(4, 4 * S), 8, 3),
        );
        assert_eq!(polar(h.step(wake, 4 * S))[0].header.stamp.frame_seq, 4);
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        use farsight_stage::DeclaresTopics;
        for toml in [
            "",
            "cameras = [\"front\", \"rear\"]",
            "method = \"fitam\"\ncameras = [\"front\", \"left\"]",
        ] {
            let h = stage(toml);
            let config: BinProjectionConfig = farsight_stage::parse_config(toml, "test").unwrap();
            let io = config.topics("bins", std::path::Path::new(".")).unwrap();
            farsight_stage::runtime::check_ports(&io, h.stage.ports()).unwrap();
            assert_eq!(h.stage.ports().inputs.len(), io.reads.len(), "{toml}");
        }
    }

    #[test]
    fn the_polar_output_has_room_for_every_bin() {
        let h = stage("method = \"fitam\"\n[fitam]\nheading_bins = 16\n");
        let out = &h.stage.ports().outputs[0];
        assert_eq!(out.topic, "bins/polar");
        assert_eq!(
            out.max_slice_bytes,
            16 * 3 * std::mem::size_of::<PolarCell>()
        );
    }
}
