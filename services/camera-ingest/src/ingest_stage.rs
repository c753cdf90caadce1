//! The camera-ingest stage as a library type ([`IngestStage`]): puts each
//! camera's frames into the graph with the camera model that goes with them
//! (`camera/<name>/info` first, then `camera/<name>/image`, then
//! `camera/<name>/depth` when the camera has a depth folder), all carrying
//! one stamp: the camera's own frame count and the capture time its
//! `capture_time` picks.
//!
//! Each camera's source (a folder, a recording, a V4L2 camera; see
//! the `sources` module) is opened in [`StageKind::new`], so a missing camera,
//! an empty folder or a damaged recording is a start-up error before the
//! stage says it is ready. The sources read and pace themselves in their own
//! threads, because decoding and capture block; the step only takes what
//! they read out of a channel and sends it, so the bus is written from the
//! runtime's thread alone.
//!
//! Lock-step pacing (`pace_by`): a camera's next frame is held until the
//! consumer's output for its previous frame has arrived (a `frame_seq` at
//! least the previous frame's), or `pace_timeout_s` has passed on the wall
//! clock, which is counted and logged. While a frame is held nothing else
//! is taken from the channel, so the sources block on it rather than pile
//! frames up in memory.
//!
//! The stage's work ends with its sources: when every camera has played all
//! it had, the process exits 0; a recording cut short (reported as degraded
//! from the start, naming the file and where it ends) is played up to the
//! cut, then the process exits 1 naming it; a source that fails under the
//! stage (the file changing while it plays) sets the health to error and
//! exits 1. Time comes only from the step (`wall_ns`), so tests drive it.

use crate::mcap_source::Truncation;
use crate::sources::{Event, Frame, Source};
use crate::{CaptureTime, IngestConfig};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::message::Image;
use farsight_interfaces::msg::{HealthState, ImageHeader, Stamp};
use farsight_interfaces::topics;
use farsight_stage::{HealthReport, Outbox, Ports, Stage, StageEnv, StageKind, Step};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TryRecvError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// How often the step looks for frames. The sources run in their own
/// threads and cannot wake the runtime's wait (only bus inputs and the tick
/// do), so the step polls their channel: a millisecond is all the delay it
/// adds to a frame, small next to any camera's period (10 ms at 100 Hz),
/// and a step over an empty channel costs next to nothing. A consumer's
/// answer wakes the step itself, so a paced frame goes the moment it may.
const TICK: Duration = Duration::from_millis(1);

/// A wall-clock offset past which a camera's capture times are taken for a
/// recording's (worth a warning: a graph on the wall clock judges them stale).
const FAR_FROM_WALL_NS: u64 = 3_600_000_000_000;

/// The camera-ingest stage: its cameras, their sources and the frame held
/// for a consumer.
pub struct IngestStage {
    ports: Ports,
    cameras: Vec<CameraOut>,
    /// The opened sources, started at the first step: by then the outputs
    /// exist, so no frame waits for the bus to open, and a source's pace
    /// starts when its frames can go out.
    unstarted: Vec<Source>,
    started: bool,
    /// Given to the sources when they start, then dropped, so the channel
    /// reports them all gone when the last one ends.
    tx: Option<SyncSender<Event>>,
    rx: Option<Receiver<Event>>,
    /// The most events one step takes: what the channel holds, so the step
    /// keeps up with every source yet never runs unbounded behind a fast one
    /// (health and a stop request are seen between steps).
    per_step: usize,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    /// Recordings cut short: (camera, where). Played up to the cut, then
    /// the stage exits 1 naming it.
    truncated: Vec<(usize, Truncation)>,
    /// Per input (each a `pace_by` topic): the `frame_seq` of the consumer's
    /// newest answer.
    answered: Vec<Option<u64>>,
    held: Option<Held>,
    ended: usize,
    pace_timeouts: u64,
}

/// One camera's model, stamping rule, output ports and frame count.
struct CameraOut {
    camera: Camera,
    capture_time: CaptureTime,
    image: usize,
    info: usize,
    depth: Option<usize>,
    pace: Option<Pace>,
    /// The `frame_seq` of the last frame sent (0: none yet).
    seq: u64,
}

/// Lock-step with a consumer: the input carrying its answers, and how long
/// a frame waits for one.
#[derive(Clone, Copy)]
struct Pace {
    input: usize,
    timeout_ns: u64,
}

/// A paced camera's frame waiting for the consumer's answer to the one
/// before, since the wall time `since_ns`.
struct Held {
    frame: Frame,
    since_ns: u64,
}

impl StageKind for IngestStage {
    const KIND: &'static str = "camera-ingest";
    type Config = IngestConfig;

    fn new(config: IngestConfig, env: &StageEnv) -> anyhow::Result<Self> {
        let base = env.config_dir.as_path();
        let models: Vec<Camera> = config
            .cameras
            .iter()
            .enumerate()
            .map(|(i, c)| c.model.build(i as u32, base))
            .collect::<Result<_, _>>()?;
        let mut ports = Ports {
            tick: Some(TICK),
            health_rate_hz: config.health_rate_hz,
            ..Ports::default()
        };
        let mut cameras = Vec::with_capacity(models.len());
        for (entry, camera) in config.cameras.iter().zip(models) {
            let (w, h) = (camera.model.width as usize, camera.model.height as usize);
            let image = ports.slice_output(topics::camera_image(&camera.name).name(), w * h * 3);
            let info = ports.output(topics::camera_info(&camera.name).name());
            let depth = (!entry.depth_folder.is_empty())
                .then(|| ports.slice_output(topics::depth(&camera.name).name(), w * h * 2));
            let pace = if entry.pace_by.is_empty() {
                None
            } else {
                topics::validate_name(&entry.pace_by).map_err(anyhow::Error::from)?;
                // Cameras paced by one consumer share its input. Answers
                // wake the step: a held frame goes as soon as it may.
                let input = match ports.input_index(&entry.pace_by) {
                    Some(i) => i,
                    None => ports.waking_input(entry.pace_by.as_str()),
                };
                let timeout = Duration::from_secs_f64(entry.pace_timeout_s);
                Some(Pace {
                    input,
                    timeout_ns: u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX),
                })
            };
            cameras.push(CameraOut {
                camera,
                capture_time: entry.capture_time,
                image,
                info,
                depth,
                pace,
                seq: 0,
            });
        }
        // Every source is opened before the stage is ready: a missing
        // camera or an empty folder is a start-up error, not a silent stream.
        let mut unstarted = Vec::with_capacity(cameras.len());
        let mut truncated = Vec::new();
        for (i, (entry, out)) in config.cameras.iter().zip(&cameras).enumerate() {
            let (source, cut) = Source::open(entry, &out.camera, base)?;
            truncated.extend(cut.map(|t| (i, t)));
            unstarted.push(source);
        }
        let per_step = 2 * cameras.len();
        let (tx, rx) = sync_channel(per_step);
        Ok(Self {
            answered: vec![None; ports.inputs.len()],
            ports,
            cameras,
            unstarted,
            started: false,
            tx: Some(tx),
            rx: Some(rx),
            per_step,
            stop: Arc::new(AtomicBool::new(false)),
            threads: Vec::new(),
            truncated,
            held: None,
            ended: 0,
            pace_timeouts: 0,
        })
    }
}

impl Stage for IngestStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        if !self.started {
            self.start(step.health);
        }
        for (input, answered) in self.answered.iter_mut().enumerate() {
            if let Some(answer) = step.inbox.take::<Image>(input) {
                *answered = Some(answer.header.stamp.frame_seq);
            }
        }
        for _ in 0..self.per_step {
            if let Some(held) = self.held.take() {
                if !self.may_go(&held, step.wall_ns) {
                    self.held = Some(held);
                    return;
                }
                self.send(held.frame, step);
            }
            let Some(rx) = &self.rx else { return };
            match rx.try_recv() {
                Ok(Event::Frame(frame)) => {
                    step.health.input();
                    let camera = &self.cameras[frame.camera];
                    // A paced camera's first frame has nothing to wait for.
                    if camera.pace.is_some() && camera.seq > 0 {
                        self.held = Some(Held {
                            frame,
                            since_ns: step.wall_ns,
                        });
                    } else {
                        self.send(frame, step);
                    }
                }
                Ok(Event::Dropped(why)) => {
                    step.health.input();
                    step.health.dropped(&why);
                }
                Ok(Event::Failed(camera, why)) => {
                    let name = &self.cameras[camera].camera.name;
                    tracing::error!(camera = %name, "{why}");
                    step.health.set(HealthState::ERROR, &why);
                    step.exit = Some(Err(format!("camera {name}: {why}")));
                    return;
                }
                Ok(Event::End(camera)) => {
                    self.ended += 1;
                    let c = &self.cameras[camera];
                    tracing::info!(camera = %c.camera.name, published = c.seq, "all frames published");
                    if self.ended == self.cameras.len() {
                        step.exit = Some(self.played_to_the_end());
                        return;
                    }
                }
                Err(TryRecvError::Empty) => return,
                // Every source gone without ending (a camera's thread that
                // lost the stage): nothing more will come.
                Err(TryRecvError::Disconnected) => {
                    step.exit = Some(Ok(()));
                    return;
                }
            }
        }
        // A held frame whose answer came with this step's last event.
        if let Some(held) = self.held.take() {
            if self.may_go(&held, step.wall_ns) {
                self.send(held.frame, step);
            } else {
                self.held = Some(held);
            }
        }
    }

    fn stop(&mut self, _out: &mut Outbox) {
        self.stop_sources();
    }
}

impl Drop for IngestStage {
    fn drop(&mut self) {
        self.stop_sources();
    }
}

impl IngestStage {
    /// Starts the sources and sets the health they begin with.
    fn start(&mut self, health: &mut HealthReport) {
        self.started = true;
        if let Some(tx) = self.tx.take() {
            for (i, source) in self.unstarted.drain(..).enumerate() {
                let handle = source.spawn(i, tx.clone(), self.stop.clone());
                self.threads.push(handle);
            }
        }
        match self.truncated.first() {
            Some((_, t)) => {
                let name = Path::new(&t.path)
                    .file_name()
                    .map_or(t.path.clone(), |n| n.to_string_lossy().into_owned());
                health.set(
                    HealthState::DEGRADED,
                    &format!("{name} truncated at byte {}", t.offset),
                );
            }
            None => health.set(HealthState::OK, ""),
        }
    }

    /// Whether a held frame may go at `now_ns`: its consumer has answered
    /// the frame before it, or it waited `pace_timeout_s` (counted, logged).
    fn may_go(&mut self, held: &Held, now_ns: u64) -> bool {
        let camera = &self.cameras[held.frame.camera];
        let Some(pace) = camera.pace else {
            return true;
        };
        if self.answered[pace.input].is_some_and(|seq| seq >= camera.seq) {
            return true;
        }
        if now_ns.saturating_sub(held.since_ns) < pace.timeout_ns {
            return false;
        }
        self.pace_timeouts += 1;
        tracing::warn!(
            pace_timeouts = self.pace_timeouts,
            camera = %camera.camera.name,
            "consumer did not take frame {} in time",
            camera.seq
        );
        true
    }

    /// Sends one frame: the camera model, the image, the depth image, all
    /// with the frame's stamp.
    fn send(&mut self, frame: Frame, step: &mut Step<'_>) {
        let now = step.wall_ns;
        let out = &mut self.cameras[frame.camera];
        out.seq += 1;
        let stamp = Stamp::new(out.seq, out.capture_time.pick(frame.capture_time_ns, now));
        // Source times far from the wall clock (a recording): say once why
        // a graph on the wall clock will not move on them.
        if out.seq == 1 && now.abs_diff(stamp.capture_time_ns) > FAR_FROM_WALL_NS {
            tracing::warn!(
                camera = %out.camera.name,
                offset_s = (stamp.capture_time_ns as f64 - now as f64) * 1e-9,
                "frames carry their source's capture times, over an hour from the wall clock: \
                 stages on the wall clock judge them stale (the servo will not move); \
                 set capture_time = \"publish\" to stamp them as they go out, or run the graph on clock = \"stamps\""
            );
        }
        let camera_id = out.camera.id;
        // The camera model goes first: a consumer that needs it (depth
        // normals, bin projection) can use the very first frame.
        step.out.send(out.info, out.camera.to_info(stamp));
        // A frame the source still holds (a looping folder's cache) is
        // copied; one it gave up is moved.
        let data = Arc::try_unwrap(frame.data).unwrap_or_else(|shared| shared.as_ref().clone());
        step.out.send(
            out.image,
            Image {
                header: ImageHeader {
                    stamp,
                    camera_id,
                    ..frame.header
                },
                data,
            },
        );
        // The depth image goes out with the frame's stamp, so consumers can pair them.
        if let (Some((header, data)), Some(port)) = (frame.depth, out.depth) {
            step.out.send(
                port,
                Image {
                    header: ImageHeader {
                        stamp,
                        camera_id,
                        ..header
                    },
                    data,
                },
            );
        }
        step.health.output(stamp, now);
    }

    /// How the stage ends once every source has played all it had: a
    /// recording that was cut short is reported with where it ends.
    fn played_to_the_end(&self) -> Result<(), String> {
        match self.truncated.first() {
            Some((camera, t)) => Err(format!(
                "camera {}: {t}; published {} frames before the cut",
                self.cameras[*camera].camera.name, self.cameras[*camera].seq
            )),
            None => Ok(()),
        }
    }

    /// Stops the source threads and waits for them: closing the channel
    /// wakes one blocked on sending; one asleep (pacing, capturing) sees
    /// the flag when it wakes.
    fn stop_sources(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.tx = None;
        self.rx = None;
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::message::Message;
    use farsight_interfaces::msg::{CameraInfo, PixelEncoding};
    use farsight_stage::runtime::Harness;
    use farsight_stage::Wake;
    use std::path::PathBuf;
    use std::time::Instant;

    const MS: u64 = 1_000_000;
    const S: u64 = 1_000_000_000;
    const NAV: &str = "perception/front/navigability";

    /// A fresh folder under the temp dir, removed when dropped.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(name: &str) -> Self {
            let dir =
                std::env::temp_dir().join(format!("ingest-stage-{name}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            Self(dir)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// Writes `names` as 8x4 RGB PNGs into `dir/sub`, each filled with its index.
    fn frames(dir: &Path, sub: &str, names: &[&str]) {
        let folder = dir.join(sub);
        std::fs::create_dir_all(&folder).unwrap();
        let h = ImageHeader::packed(Stamp::default(), 0, 8, 4, PixelEncoding::RGB8);
        for (k, name) in names.iter().enumerate() {
            let png = farsight_imaging::encode_png(&h, &[k as u8; 8 * 4 * 3]).unwrap();
            std::fs::write(folder.join(name), png).unwrap();
        }
    }

    /// A camera entry for an 8x4 camera named `name` with `keys`.
    fn camera(name: &str, keys: &str) -> String {
        format!(
            "[[cameras]]\n{keys}\n[cameras.model]\nname = \"{name}\"\nwidth = 8\nheight = 4\nfx = 6.0\nfy = 6.0\ncx = 4.0\ncy = 2.0\n"
        )
    }

    fn config(toml: &str) -> IngestConfig {
        farsight_stage::parse_config(toml, "test").unwrap()
    }

    fn build(toml: &str, dir: &Path) -> anyhow::Result<IngestStage> {
        let env = StageEnv {
            instance: "camera-ingest".into(),
            config_dir: dir.to_path_buf(),
        };
        IngestStage::new(config(toml), &env)
    }

    fn stage(toml: &str, dir: &Path) -> Harness<IngestStage> {
        Harness::new(build(toml, dir).unwrap())
    }

    /// Steps on the tick at wall time `wall_ns` (real time passing, so the
    /// sources run) until `done` says so; returns what was sent.
    fn step_until(
        h: &mut Harness<IngestStage>,
        wall_ns: u64,
        mut done: impl FnMut(&Harness<IngestStage>, &[(String, Message)]) -> bool,
    ) -> Vec<(String, Message)> {
        let mut sent = Vec::new();
        let give_up = Instant::now() + Duration::from_secs(10);
        while !done(h, &sent) {
            assert!(Instant::now() < give_up, "gave up waiting; sent {sent:?}");
            std::thread::sleep(Duration::from_millis(1));
            sent.extend(h.step(Wake::Tick, wall_ns));
        }
        sent
    }

    fn image(m: &Message) -> &Image {
        match m {
            Message::Image(i) => i,
            other => panic!("not an image: {other:?}"),
        }
    }

    fn info(m: &Message) -> &CameraInfo {
        match m {
            Message::CameraInfo(i) => i,
            other => panic!("not a camera model: {other:?}"),
        }
    }

    fn topics_of(sent: &[(String, Message)]) -> Vec<&str> {
        sent.iter().map(|(t, _)| t.as_str()).collect()
    }

    #[test]
    fn each_frame_goes_out_model_first_with_the_next_seq_then_the_stage_exits() {
        let dir = TempDir::new("order");
        frames(
            &dir.0,
            "front",
            &[
                "1000000000001.png",
                "1000000000002.png",
                "1000000000003.png",
            ],
        );
        let mut h = stage(
            &camera("front", "folder = \"front\"\nrate_hz = 500.0"),
            &dir.0,
        );
        let sent = step_until(&mut h, 5 * S, |h, _| h.exit.is_some());
        assert_eq!(h.exit, Some(Ok(())), "every source ended");
        assert_eq!(
            topics_of(&sent),
            ["camera/front/info", "camera/front/image"].repeat(3)
        );
        for (k, pair) in sent.chunks(2).enumerate() {
            let (model, frame) = (info(&pair[0].1), image(&pair[1].1));
            let seq = k as u64 + 1;
            assert_eq!(frame.header.stamp.frame_seq, seq);
            // Named by Unix milliseconds: the names are the capture times.
            assert_eq!(
                frame.header.stamp.capture_time_ns,
                1_000_000_000_000_000_000 + seq * MS
            );
            assert_eq!(model.stamp, frame.header.stamp, "one stamp for both");
            assert_eq!((model.width, model.height), (8, 4));
            assert_eq!(frame.data, vec![k as u8; 8 * 4 * 3]);
        }
        assert_eq!(h.health.state(), HealthState::OK);
        let report = h.health.report();
        assert_eq!((report.messages_in, report.messages_out), (3, 3));
    }

    #[test]
    fn publish_time_stamps_come_from_the_steps_wall_clock() {
        let dir = TempDir::new("publish");
        frames(&dir.0, "front", &["1000000000001.png"]);
        let keys = "folder = \"front\"\ncapture_time = \"publish\"";
        let mut h = stage(&camera("front", keys), &dir.0);
        let sent = step_until(&mut h, 42 * S, |_, sent| !sent.is_empty());
        assert_eq!(image(&sent[1].1).header.stamp.capture_time_ns, 42 * S);
    }

    #[test]
    fn a_paced_camera_holds_its_next_frame_until_the_consumer_answers() {
        let dir = TempDir::new("paced");
        frames(&dir.0, "front", &["a.png", "b.png", "c.png"]);
        let keys = format!(
            "folder = \"front\"\nrate_hz = 500.0\npace_by = \"{NAV}\"\npace_timeout_s = 60.0"
        );
        let mut h = stage(&camera("front", &keys), &dir.0);
        let first = step_until(&mut h, S, |_, sent| sent.len() == 2);
        assert_eq!(
            image(&first[1].1).header.stamp.frame_seq,
            1,
            "nothing to wait for"
        );
        // Frame 2 arrives and is held: no answer to frame 1 yet.
        let held = step_until(&mut h, S, |h, _| h.stage.held.is_some());
        assert!(held.is_empty(), "{held:?}");
        assert!(
            h.step(Wake::Tick, 2 * S).is_empty(),
            "still within the timeout"
        );
        // An answer to an older frame does not count.
        let answer = |seq| Image {
            header: ImageHeader::packed(Stamp::new(seq, 0), 0, 8, 4, PixelEncoding::MONO8),
            data: vec![0; 32],
        };
        let wake = h.wake_on(NAV);
        h.put(NAV, answer(0));
        assert!(h.step(wake, 2 * S).is_empty());
        h.put(NAV, answer(1));
        let second = h.step(wake, 2 * S);
        assert_eq!(
            topics_of(&second),
            ["camera/front/info", "camera/front/image"]
        );
        assert_eq!(image(&second[1].1).header.stamp.frame_seq, 2);
        assert_eq!(h.stage.pace_timeouts, 0);
        // The answer is remembered past its step, but frame 3 waits for one to frame 2.
        let held = step_until(&mut h, 2 * S, |h, _| h.stage.held.is_some());
        assert!(held.is_empty(), "{held:?}");
        h.put(NAV, answer(2));
        let third = h.step(wake, 2 * S);
        assert_eq!(image(&third[1].1).header.stamp.frame_seq, 3);
        let sent = step_until(&mut h, 2 * S, |h, _| h.exit.is_some());
        assert!(sent.is_empty());
        assert_eq!(h.exit, Some(Ok(())));
    }

    #[test]
    fn a_paced_frame_goes_after_the_timeout_without_an_answer_and_is_counted() {
        let dir = TempDir::new("timeout");
        frames(&dir.0, "front", &["a.png", "b.png"]);
        let keys = format!(
            "folder = \"front\"\nrate_hz = 500.0\npace_by = \"{NAV}\"\npace_timeout_s = 0.5"
        );
        let mut h = stage(&camera("front", &keys), &dir.0);
        step_until(&mut h, 10 * S, |_, sent| sent.len() == 2);
        step_until(&mut h, 10 * S, |h, _| h.stage.held.is_some());
        assert!(h.step(Wake::Tick, 10 * S + 499 * MS).is_empty());
        let sent = h.step(Wake::Tick, 10 * S + 500 * MS);
        assert_eq!(image(&sent[1].1).header.stamp.frame_seq, 2);
        assert_eq!(h.stage.pace_timeouts, 1);
    }

    #[test]
    fn depth_goes_out_after_its_frame_with_the_frames_stamp() {
        let dir = TempDir::new("depth");
        frames(&dir.0, "front", &["a.png", "b.png"]);
        std::fs::create_dir_all(dir.0.join("depth")).unwrap();
        let depth = ImageHeader::packed(Stamp::default(), 0, 8, 4, PixelEncoding::MONO16);
        let png = farsight_imaging::encode_png(&depth, &[3u8; 8 * 4 * 2]).unwrap();
        std::fs::write(dir.0.join("depth/a.png"), png).unwrap();
        // b.png has no depth image: dropped and counted, the frame still goes.
        let keys = "folder = \"front\"\nrate_hz = 500.0\ndepth_folder = \"depth\"";
        let mut h = stage(&camera("front", keys), &dir.0);
        let sent = step_until(&mut h, S, |h, _| h.exit.is_some());
        assert_eq!(
            topics_of(&sent),
            [
                "camera/front/info",
                "camera/front/image",
                "camera/front/depth",
                "camera/front/info",
                "camera/front/image"
            ]
        );
        let (frame, depth) = (image(&sent[1].1), image(&sent[2].1));
        assert_eq!(depth.header.stamp, frame.header.stamp);
        assert_eq!(depth.header.encoding, PixelEncoding::MONO16);
        assert_eq!(h.health.report().dropped, 1);
    }

    #[test]
    fn a_cut_recording_is_degraded_played_to_the_cut_then_fails_naming_it() {
        let dir = TempDir::new("cut");
        let whole = dir.0.join("whole.mcap");
        let mut w =
            farsight_recording::write::RecordingWriter::create_with(&whole, false, false).unwrap();
        for k in 1..=3u64 {
            let h = ImageHeader::packed(Stamp::new(k, k * S), 0, 8, 4, PixelEncoding::RGB8);
            let bytes = farsight_interfaces::transport::wire::encode_slice(&h, &[k as u8; 96]);
            w.write("camera/front/image", h.stamp, k * S, &bytes.unwrap())
                .unwrap();
        }
        w.finish().unwrap();
        // The longest cut of the file that still holds frames: the stage
        // plays those, however the writer chunked them.
        let bytes = std::fs::read(&whole).unwrap();
        let cut = dir.0.join("cut.mcap");
        let at = (1..bytes.len())
            .rev()
            .find_map(|len| {
                std::fs::write(&cut, &bytes[..len]).unwrap();
                let file = crate::mcap_source::McapFile::open(&cut).ok()?;
                let t = file.contents().ok()?.truncated?;
                (t.messages > 0).then_some(t)
            })
            .expect("a cut that keeps a frame");
        let keys =
            "source = \"mcap\"\nfile = \"cut.mcap\"\ntopic = \"camera/front/image\"\nspeed = 100.0";
        let mut h = stage(&camera("front", keys), &dir.0);
        let sent = step_until(&mut h, S, |h, _| h.exit.is_some());
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert_eq!(
            h.health.report().reason.as_str(),
            format!("cut.mcap truncated at byte {}", at.offset)
        );
        let played = sent.len() as u64 / 2;
        assert_eq!(played, at.messages, "every whole frame");
        let why = h.exit.clone().unwrap().unwrap_err();
        assert!(
            why.starts_with(&format!(
                "camera front: {}: truncated at byte {}",
                cut.display(),
                at.offset
            )) && why.ends_with(&format!("published {played} frames before the cut")),
            "{why}"
        );
    }

    #[test]
    fn start_up_errors_name_the_camera_and_what_is_wrong() {
        let dir = TempDir::new("errors");
        std::fs::create_dir_all(dir.0.join("empty")).unwrap();
        let err = |keys: &str| match build(&camera("front", keys), &dir.0) {
            Ok(_) => panic!("{keys}: started"),
            Err(e) => format!("{e:#}"),
        };
        let e = err("folder = \"empty\"");
        assert!(
            e.starts_with("camera front: folder") && e.ends_with("holds no PNG or JPEG images"),
            "{e}"
        );
        let e = err("folder = \"absent\"");
        assert!(
            e.starts_with("camera front: folder") && e.contains("absent"),
            "{e}"
        );
        let e = err("source = \"mcap\"\nfile = \"absent.mcap\"\ntopic = \"t\"");
        assert!(
            e.starts_with("camera front: ") && e.contains("absent.mcap"),
            "{e}"
        );
    }

    #[test]
    fn stopping_ends_a_source_that_would_play_forever() {
        let dir = TempDir::new("stop");
        frames(&dir.0, "front", &["a.png"]);
        let keys = "folder = \"front\"\nrate_hz = 500.0\nloops = 0";
        let mut h = stage(&camera("front", keys), &dir.0);
        step_until(&mut h, S, |_, sent| sent.len() >= 6);
        assert!(h.stop().is_empty(), "no last words");
        assert!(h.stage.threads.is_empty(), "the source threads were joined");
        assert!(h.step(Wake::Tick, S).is_empty(), "nothing after a stop");
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        use farsight_stage::DeclaresTopics;
        let dir = TempDir::new("ports");
        frames(&dir.0, "front", &["a.png"]);
        let paced = format!("folder = \"front\"\npace_by = \"{NAV}\"");
        for toml in [
            camera("front", "folder = \"front\""),
            camera("front", &paced)
                + &camera("rear", &paced)
                + &camera("down", "folder = \"front\"\ndepth_folder = \"depth\""),
        ] {
            let h = stage(&toml, &dir.0);
            let io = config(&toml).topics("camera-ingest", &dir.0).unwrap();
            farsight_stage::runtime::check_ports(&io, h.stage.ports()).unwrap();
            let inputs = &h.stage.ports().inputs;
            assert!(inputs.iter().all(|i| i.wakes), "answers wake the step");
            assert!(inputs.len() <= 1, "one input per consumer: {inputs:?}");
        }
    }
}
