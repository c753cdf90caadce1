//! `farsight inspect`: the robot's graph as a laptop sees it over zenoh
//! (what the robot's bridge exports).
//!
//! ```text
//! farsight inspect --connect tcp/ROBOT:7447 --robot NAME            # stages, health, rates, latency
//! farsight inspect --connect tcp/ROBOT:7447 echo nav/subgoal        # messages as JSON
//! farsight inspect --connect tcp/ROBOT:7447 snapshot --out snap     # camera with overlays, costmap: PNG
//! ```
//!
//! A stage is alive when its health arrived in the last `--seconds` window.
//! Latency is receive time minus the capture time each message carries, on
//! the wall clock (robot and laptop clocks must agree, e.g. by NTP/PTP); a
//! recording or simulation's clock shows as "-".

use crate::memory::ProcessMemory;
use anyhow::{bail, Context, Result};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::*;
use farsight_interfaces::topics::{kind_of, TopicKind};
use farsight_interfaces::transport::any::wire_stamp;
use farsight_interfaces::transport::net::NetBus;
use farsight_interfaces::transport::wire;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// The robot's zenoh endpoint(s).
    #[arg(long, value_delimiter = ',', default_value = "tcp/127.0.0.1:7447")]
    pub connect: Vec<String>,
    /// The robot's name (the <robot> of its zenoh keys).
    #[arg(long, default_value = "robot")]
    pub robot: String,
    /// How long to listen.
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    #[command(flatten)]
    pub login: crate::Login,
    #[command(subcommand)]
    pub command: Option<InspectCommand>,
}

#[derive(Debug, clap::Subcommand)]
pub enum InspectCommand {
    /// Print a topic's messages as JSON (slices: header and length).
    Echo {
        topic: String,
        #[arg(long, default_value_t = 5)]
        count: usize,
    },
    /// Write the newest camera frame with the navigability mask, visual path
    /// and subgoal drawn on it, and the fused costmap, as PNG files.
    Snapshot {
        #[arg(long, default_value = "front")]
        camera: String,
        #[arg(long, default_value = "snapshot")]
        out: PathBuf,
    },
}

/// Per topic: messages seen, over what time, and their latency.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopicView {
    pub count: u64,
    pub first_ns: u64,
    pub last_ns: u64,
    /// Sum and count of wall-clock latencies (ms).
    pub latency_ms: (f64, u64),
}

/// What the laptop has seen of the graph.
#[derive(Debug, Clone, Default)]
pub struct GraphView {
    pub topics: BTreeMap<String, TopicView>,
    pub health: BTreeMap<String, StageHealth>,
    /// Per stage: the smallest (receive time here - report time there) of
    /// its health reports, in ms. Each report is stamped with the stage's
    /// wall clock, so this is the stage clock's lag behind this machine's
    /// plus the shortest transport delay seen (NTP's minimum-delay filter):
    /// a large value, or a negative one, means the clocks disagree, and
    /// staleness judged on capture times across machines is then wrong.
    pub clock_offset_ms: BTreeMap<String, f64>,
    /// Per stage whose process runs on this machine: its private memory
    /// and the shared memory it maps ([`crate::memory`]).
    pub memory: BTreeMap<String, ProcessMemory>,
}

/// Capture times before this are not wall-clock (a replay or simulation's clock).
const WALL_CLOCK_AFTER_NS: u64 = 1_500_000_000_000_000_000;

impl GraphView {
    /// Takes one message received at `now_ns`.
    pub fn observe(&mut self, topic: &str, bytes: &[u8], now_ns: u64) {
        let Ok(stamp) = wire_stamp(topic, bytes) else {
            return;
        };
        let t = self.topics.entry(topic.to_string()).or_default();
        if t.count == 0 {
            t.first_ns = now_ns;
        }
        t.count += 1;
        t.last_ns = now_ns;
        if stamp.capture_time_ns > WALL_CLOCK_AFTER_NS && now_ns >= stamp.capture_time_ns {
            t.latency_ms.0 += (now_ns - stamp.capture_time_ns) as f64 * 1e-6;
            t.latency_ms.1 += 1;
        }
        if kind_of(topic) == Some(TopicKind::Health) {
            if let Ok(h) = wire::decode_message::<StageHealth>(bytes) {
                let name = h.stage.as_str().to_string();
                if h.stamp.capture_time_ns > WALL_CLOCK_AFTER_NS {
                    let seen_ms = (now_ns as i128 - h.stamp.capture_time_ns as i128) as f64 * 1e-6;
                    let offset = self.clock_offset_ms.entry(name.clone()).or_insert(seen_ms);
                    *offset = offset.min(seen_ms);
                }
                self.health.insert(name, h);
            }
        }
    }

    /// Reads the memory of every stage whose process runs here.
    pub fn read_local_memory(&mut self) {
        for (name, h) in &self.health {
            if crate::memory::is_local_farsight_process(h.pid) {
                if let Some(m) = crate::memory::of_pid(h.pid) {
                    self.memory.insert(name.clone(), m);
                }
            }
        }
    }

    /// The one-screen report.
    pub fn render(&self) -> String {
        let mut s = String::from("stages (alive: health heard)\n");
        s += &format!(
            "  {:<20} {:<9} {:>8} {:>8} {:>7} {:>7} {:>10} {:>9} {:>10} {:>8}  reason\n",
            "stage",
            "state",
            "in",
            "out",
            "dropped",
            "skipped",
            "latency ms",
            "clock ms",
            "private MB",
            "shm MB"
        );
        for (name, h) in &self.health {
            // A stage on a replay's or simulation's clock measures its
            // latency against the wall clock: nonsense, shown as "-".
            let latency = if (0.0..86_400_000.0).contains(&h.last_latency_ms) {
                format!("{:.1}", h.last_latency_ms)
            } else {
                "-".into()
            };
            // The stage clock's lag behind this machine's, upper-bounded by
            // the transport delay ("-": the stage runs on a replay's clock).
            let clock = self
                .clock_offset_ms
                .get(name)
                .map_or_else(|| "-".to_string(), |ms| format!("{ms:+.1}"));
            // Memory: only for a stage running on this machine ("-" else).
            let (private, shm) = self.memory.get(name).map_or_else(
                || ("-".to_string(), "-".to_string()),
                |m| {
                    (
                        format!("{:.1}", crate::memory::mb(m.private_bytes)),
                        format!("{:.1}", crate::memory::mb(m.shared_memory_bytes)),
                    )
                },
            );
            s += &format!(
                "  {:<20} {:<9} {:>8} {:>8} {:>7} {:>7} {:>10} {:>9} {:>10} {:>8}  {}\n",
                name,
                h.state.name().unwrap_or("?"),
                h.messages_in,
                h.messages_out,
                h.dropped,
                h.skipped,
                latency,
                clock,
                private,
                shm,
                h.reason.as_str()
            );
        }
        s += "topics\n";
        s += &format!(
            "  {:<34} {:>8} {:>8} {:>14}\n",
            "topic", "messages", "rate Hz", "latency ms"
        );
        for (topic, t) in &self.topics {
            let span = t.last_ns.saturating_sub(t.first_ns) as f64 * 1e-9;
            let rate = if t.count > 1 && span > 0.0 {
                (t.count - 1) as f64 / span
            } else {
                0.0
            };
            let lat = if t.latency_ms.1 > 0 {
                format!("{:.1}", t.latency_ms.0 / t.latency_ms.1 as f64)
            } else {
                "-".into()
            };
            s += &format!("  {topic:<34} {:>8} {rate:>8.2} {lat:>14}\n", t.count);
        }
        s
    }
}

fn listen(a: &InspectArgs, mut on: impl FnMut(&str, &[u8], u64) -> bool) -> Result<()> {
    let config = a.login.client_config("client", &a.connect)?;
    let net =
        NetBus::open(config, &a.robot).with_context(|| format!("connecting to {:?}", a.connect))?;
    let tap = net.tap(1024)?;
    let end = Instant::now() + Duration::from_secs_f64(a.seconds);
    while Instant::now() < end {
        match tap.try_next()? {
            Some((topic, bytes)) => {
                if !on(&topic, &bytes, WallClock.now_ns()) {
                    return Ok(());
                }
            }
            None => std::thread::sleep(Duration::from_millis(2)),
        }
    }
    Ok(())
}

pub fn run(a: InspectArgs) -> Result<()> {
    match &a.command {
        None => {
            let mut view = GraphView::default();
            listen(&a, |t, b, now| {
                view.observe(t, b, now);
                true
            })?;
            if view.topics.is_empty() {
                bail!(
                    "nothing heard from robot {:?} at {:?} in {} s",
                    a.robot,
                    a.connect,
                    a.seconds
                );
            }
            view.read_local_memory();
            print!("{}", view.render());
        }
        Some(InspectCommand::Echo { topic, count }) => {
            let mut n = 0;
            listen(&a, |t, b, _| {
                if t == topic {
                    match farsight_recording::diff::decode(t, b) {
                        Ok(d) => {
                            let len = d
                                .bytes
                                .as_ref()
                                .map(Vec::len)
                                .or(d.floats.as_ref().map(Vec::len));
                            println!(
                                "{}{}",
                                d.fields,
                                len.map_or(String::new(), |l| format!(" ({l} elements)"))
                            );
                        }
                        Err(e) => println!("undecodable: {e}"),
                    }
                    n += 1;
                }
                n < *count
            })?;
            if n == 0 {
                bail!("no message on {topic} in {} s", a.seconds);
            }
        }
        Some(InspectCommand::Snapshot { camera, out }) => {
            let mut newest: BTreeMap<String, Vec<u8>> = BTreeMap::new();
            listen(&a, |t, b, _| {
                newest.insert(t.to_string(), b.to_vec());
                true
            })?;
            std::fs::create_dir_all(out)?;
            let written = snapshot(&newest, camera, out)?;
            if written.is_empty() {
                bail!(
                    "no camera/{camera}/image and no costmap heard in {} s",
                    a.seconds
                );
            }
            for p in written {
                println!("{}", p.display());
            }
        }
    }
    Ok(())
}

fn decode_frame(bytes: &[u8]) -> Result<(ImageHeader, Vec<u8>)> {
    let (h, d) = wire::split_slice::<ImageHeader>(bytes)?;
    if h.encoding.is_compressed() {
        Ok(farsight_imaging::decode_image(d)?)
    } else {
        h.validate(d.len())?;
        Ok((h, d.to_vec()))
    }
}

/// The newest camera frame with overlays (navigability green, visual path
/// orange, subgoal red; all scaled to the frame's size) and the fused
/// costmap in grey (lighter = cheaper, black = lethal, blue = unknown).
pub fn snapshot(
    newest: &BTreeMap<String, Vec<u8>>,
    camera: &str,
    out: &std::path::Path,
) -> Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    if let Some(bytes) = newest.get(&format!("camera/{camera}/image")) {
        let (h, mut rgb) = decode_frame(bytes)?;
        if h.encoding != PixelEncoding::RGB8 {
            bail!("camera/{camera}/image is {}, not rgb8", h.encoding);
        }
        let (w, ht) = (h.width as usize, h.height as usize);
        if let Some(nb) = newest.get(&format!("perception/{camera}/navigability")) {
            let (nh, nav) = decode_frame(nb)?;
            let (nw, nht) = (nh.width as usize, nh.height as usize);
            for y in 0..ht {
                for x in 0..w {
                    if nav[(y * nht / ht) * nw + x * nw / w] > 127 {
                        let p = &mut rgb[(y * w + x) * 3..][..3];
                        p[1] = p[1].saturating_add(70);
                    }
                }
            }
        }
        let mut dot = |u: f64, v: f64, scale: (f64, f64), c: [u8; 3]| {
            let (x, y) = ((u * scale.0) as i64, (v * scale.1) as i64);
            for dy in -2..=2 {
                for dx in -2..=2 {
                    let (px, py) = (x + dx, y + dy);
                    if px >= 0 && py >= 0 && (px as usize) < w && (py as usize) < ht {
                        rgb[(py as usize * w + px as usize) * 3..][..3].copy_from_slice(&c);
                    }
                }
            }
        };
        // Paths and subgoals are in the full-size image's pixels; the frame
        // may have been downsampled on the way (the bridge): scale by the
        // camera model's size when it came along.
        let scale = newest
            .get(&format!("camera/{camera}/info"))
            .and_then(|b| wire::decode_message::<CameraInfo>(b).ok())
            .map_or((1.0, 1.0), |i| {
                (w as f64 / i.width as f64, ht as f64 / i.height as f64)
            });
        if let Some(p) = newest
            .get("nav/path/visual")
            .and_then(|b| wire::decode_message::<Path>(b).ok())
        {
            for q in p.points.as_slice() {
                dot(q[0] as f64, q[1] as f64, scale, [255, 150, 0]);
            }
        }
        if let Some(s) = newest
            .get("nav/subgoal")
            .and_then(|b| wire::decode_message::<Subgoal>(b).ok())
            .filter(|s| s.image_u_px.is_finite())
        {
            dot(s.image_u_px as f64, s.image_v_px as f64, scale, [255, 0, 0]);
        }
        let header =
            ImageHeader::packed(h.stamp, h.camera_id, h.width, h.height, PixelEncoding::RGB8);
        let p = out.join(format!("camera-{camera}.png"));
        std::fs::write(&p, farsight_imaging::encode_png(&header, &rgb)?)?;
        written.push(p);
    }
    let heading = newest
        .get("nav/subgoal")
        .and_then(|b| wire::decode_message::<Subgoal>(b).ok())
        .map(|s| s.heading_rad as f64)
        .filter(|h| h.is_finite());
    if let Some(b) = newest
        .get("bins/angular")
        .and_then(|b| wire::decode_message::<AngularBins>(b).ok())
    {
        let (header, rgb) = polar_plot(&b, heading);
        let p = out.join("bins-angular.png");
        std::fs::write(&p, farsight_imaging::encode_png(&header, &rgb)?)?;
        written.push(p);
    }
    for layer in ["fused", "local"] {
        let Some(bytes) = newest.get(&format!("costmap/{layer}")) else {
            continue;
        };
        let (h, cells) = wire::decode_slice::<CostmapHeader, CostCell>(bytes)?;
        let rgb: Vec<u8> = cells
            .iter()
            .flat_map(|c| {
                let s = c.cost_s_per_m;
                if s.is_nan() {
                    [40, 60, 120]
                } else if s.is_infinite() {
                    [0, 0, 0]
                } else {
                    let g = (255.0 * (1.0 - (s / 10.0).clamp(0.0, 1.0))) as u8;
                    [g, g, g]
                }
            })
            .collect();
        let header = ImageHeader::packed(h.stamp, 0, h.width, h.height, PixelEncoding::RGB8);
        let p = out.join(format!("costmap-{layer}.png"));
        std::fs::write(&p, farsight_imaging::encode_png(&header, &rgb)?)?;
        written.push(p);
    }
    Ok(written)
}

/// LRN's angular bins as a polar plot seen from above (forward up, left
/// left): each observed bin a wedge as long as its score (green), unobserved
/// bins grey, the chosen heading a red ray.
pub fn polar_plot(bins: &AngularBins, heading_rad: Option<f64>) -> (ImageHeader, Vec<u8>) {
    const S: usize = 401;
    let c = (S / 2) as f64;
    let mut rgb = vec![255u8; S * S * 3];
    let scores = bins.scores.as_slice();
    let observed = bins.observed.as_slice();
    let max = scores.iter().copied().fold(1e-6f32, f32::max) as f64;
    let width = bins.bin_width_rad as f64;
    for y in 0..S {
        for x in 0..S {
            // Robot frame: x forward (image up), y left (image left).
            let (fx, fy) = (c - y as f64, c - x as f64);
            let r = fx.hypot(fy) / c;
            if r > 1.0 {
                continue;
            }
            let a = fy.atan2(fx);
            let k = ((a - bins.first_bin_start_rad as f64) / width)
                .rem_euclid(std::f64::consts::TAU / width) as usize;
            let Some(&score) = scores.get(k) else {
                continue;
            };
            let p = &mut rgb[(y * S + x) * 3..][..3];
            if observed.get(k) != Some(&1) {
                p.copy_from_slice(&[225, 225, 225]);
            } else if r <= score as f64 / max {
                p.copy_from_slice(&[60, 170, 60]);
            }
        }
    }
    if let Some(h) = heading_rad {
        for i in 0..(c as usize) {
            let (fx, fy) = (i as f64 * h.cos(), i as f64 * h.sin());
            let (x, y) = ((c - fy) as usize, (c - fx) as usize);
            if x < S && y < S {
                rgb[(y * S + x) * 3..][..3].copy_from_slice(&[220, 0, 0]);
            }
        }
    }
    let header = ImageHeader::packed(bins.stamp, 0, S as u32, S as u32, PixelEncoding::RGB8);
    (header, rgb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_polar_plot_draws_wedges_by_score_and_the_heading_ray() {
        // 8 bins of 45 degrees from -180: bin 4 covers [0, 45) degrees (ahead-left).
        let mut scores = [0.0f32; 8];
        scores[4] = 1.0;
        let mut observed = [1u8; 8];
        observed[0] = 0;
        let bins = AngularBins {
            first_bin_start_rad: -std::f32::consts::PI,
            bin_width_rad: std::f32::consts::FRAC_PI_4,
            scores: farsight_interfaces::fixed::FixedVec::from_slice(&scores).unwrap(),
            observed: farsight_interfaces::fixed::FixedVec::from_slice(&observed).unwrap(),
            ..Default::default()
        };
        let (h, rgb) = polar_plot(&bins, Some(-std::f64::consts::FRAC_PI_2));
        let px = |x: usize, y: usize| &rgb[(y * h.width as usize + x) * 3..][..3];
        // Ahead and a little left of the centre (200, 200): bin 4's wedge.
        assert_eq!(px(190, 120), [60, 170, 60]);
        // Ahead-right (bin 3, score 0): white.
        assert_eq!(px(210, 120), [255, 255, 255]);
        // Behind and a little right is bin 0 ([-180, -135) degrees), unobserved: grey.
        assert_eq!(px(205, 330), [225, 225, 225]);
        // The heading ray points right (-90 degrees).
        assert_eq!(px(300, 200), [220, 0, 0]);
    }

    #[test]
    fn each_stages_clock_offset_is_the_smallest_lag_of_its_reports() {
        let mut v = GraphView::default();
        let t0 = 1_700_000_000_000_000_000u64;
        let mut h = StageHealth {
            stage: farsight_interfaces::fixed::FixedStr::new("inference").unwrap(),
            ..Default::default()
        };
        // The stage's clock runs 250 ms behind this machine's; its reports
        // take 3 to 40 ms to arrive.
        for (k, delay_ms) in [40u64, 3, 17].into_iter().enumerate() {
            let stage_time = t0 + k as u64 * 1_000_000_000;
            h.stamp = Stamp::new(k as u64, stage_time);
            let heard = stage_time + 250_000_000 + delay_ms * 1_000_000;
            v.observe(
                "health/inference",
                &wire::encode_message(&h).unwrap(),
                heard,
            );
        }
        assert!((v.clock_offset_ms["inference"] - 253.0).abs() < 1e-6);
        // A stage ahead of this machine shows a negative offset.
        h.stage = farsight_interfaces::fixed::FixedStr::new("bridge").unwrap();
        h.stamp = Stamp::new(1, t0 + 2_000_000_000);
        v.observe("health/bridge", &wire::encode_message(&h).unwrap(), t0);
        assert!((v.clock_offset_ms["bridge"] + 2000.0).abs() < 1e-6);
        assert!(v.render().contains("-2000.0"), "{}", v.render());
        // On a replay's clock (not wall time) there is no offset to show.
        h.stage = farsight_interfaces::fixed::FixedStr::new("servo").unwrap();
        h.stamp = Stamp::new(1, 5_000_000_000);
        v.observe(
            "health/velocity-servoing",
            &wire::encode_message(&h).unwrap(),
            t0,
        );
        assert!(!v.clock_offset_ms.contains_key("servo"));
    }

    #[test]
    fn the_view_counts_rates_latency_and_health() {
        let mut v = GraphView::default();
        let t0 = 1_700_000_000_000_000_000u64;
        for k in 0..11u64 {
            let pose = Pose {
                stamp: Stamp::new(k, t0 + k * 100_000_000),
                ..Default::default()
            };
            // Received 20 ms after capture, every 100 ms.
            v.observe(
                "state/pose",
                &wire::encode_message(&pose).unwrap(),
                t0 + k * 100_000_000 + 20_000_000,
            );
        }
        let mut h = StageHealth {
            stamp: Stamp::new(0, t0),
            state: HealthState::DEGRADED,
            ..Default::default()
        };
        h.stage = farsight_interfaces::fixed::FixedStr::new("velocity-servoing").unwrap();
        h.reason = farsight_interfaces::fixed::FixedStr::new("subgoal is 0.71 s old").unwrap();
        v.observe(
            "health/velocity-servoing",
            &wire::encode_message(&h).unwrap(),
            t0,
        );
        let t = &v.topics["state/pose"];
        assert_eq!(t.count, 11);
        assert!((t.latency_ms.0 / t.latency_ms.1 as f64 - 20.0).abs() < 1e-6);
        let text = v.render();
        assert!(text.contains("velocity-servoing"), "{text}");
        assert!(text.contains("degraded"), "{text}");
        assert!(text.contains("subgoal is 0.71 s old"), "{text}");
        assert!(
            text.lines()
                .any(|l| l.contains("state/pose") && l.contains("10.00") && l.contains("20.0")),
            "{text}"
        );
        // The health report was stamped t0 on the stage's clock and heard
        // at t0 here: clocks agree.
        assert_eq!(v.clock_offset_ms["velocity-servoing"], 0.0);
        assert!(
            text.lines()
                .any(|l| l.contains("velocity-servoing") && l.contains("+0.0")),
            "{text}"
        );
        // Garbage on a topic is ignored, not counted.
        v.observe("state/pose", b"junk", t0);
        assert_eq!(v.topics["state/pose"].count, 11);
    }

    #[test]
    fn a_stage_on_this_machine_shows_its_memory_and_a_remote_one_a_dash() {
        let mut v = GraphView::default();
        for (stage, pid) in [("here", std::process::id()), ("robot", u32::MAX)] {
            let mut h = StageHealth {
                pid,
                ..Default::default()
            };
            h.stage = farsight_interfaces::fixed::FixedStr::new(stage).unwrap();
            v.observe(
                &format!("health/{stage}"),
                &wire::encode_message(&h).unwrap(),
                1,
            );
        }
        v.read_local_memory();
        let here = v.memory["here"];
        assert!(here.private_bytes > 1 << 20, "{here}");
        assert!(!v.memory.contains_key("robot"));
        let text = v.render();
        let row = |stage: &str| {
            text.lines()
                .find(|l| l.trim_start().starts_with(stage))
                .unwrap_or_else(|| panic!("{text}"))
                .to_string()
        };
        let shown = format!("{:.1}", crate::memory::mb(here.private_bytes));
        assert!(row("here").contains(&shown), "{text}");
        assert!(
            row("robot")
                .split_whitespace()
                .filter(|w| *w == "-")
                .count()
                >= 3,
            "{text}"
        );
    }
}
