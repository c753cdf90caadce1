//! Recorded frame replays through the real stage binaries.
//!
//! The fixture `tests/fixtures/sim-povnav/` is 8 s of the POVNav demo on
//! bush-wall, recorded with every topic, with the stage configs the demo ran,
//! the graph file naming them (`graph.toml`) and the goldens (`cargo xtask
//! fixtures` regenerates all but the graph file after an intended change of
//! the outputs). Every test starts the graph through `farsight run`: the
//! fixture's graph file, or a copy with one stage's config changed; a
//! killed stage is restarted by `farsight run`. Its simulator topics are replayed
//! lock-step into inference (HSV backend) -> subgoal-selection (POVNav) ->
//! velocity-servoing, all on the stamps' clock, and every output topic is
//! compared with `golden.mcap`.

use farsight_interfaces::msg::{CommandReason, VelocityCommand};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::QUEUES_ENV;
use farsight_interfaces::transport::wire;
use farsight_recording::diff::{compare, Mismatch, Tolerance};
use farsight_recording::read::Recording;
use farsight_tests::{repo_root, Namespace, Proc};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const STAGES: [&str; 3] = ["inference", "subgoal-selection", "velocity-servoing"];
const INPUTS: &str = "camera/front/image,camera/front/info,state/pose,nav/goal";
const OUTPUTS: [&str; 4] = [
    "perception/front/navigability",
    "nav/subgoal",
    "nav/path/visual",
    "cmd/velocity",
];

/// The fixture recording, relative to the tests' working directory (the
/// `tests/` package folder).
const FIXTURE_RECORDING: &str = "fixtures/sim-povnav/recording.mcap";

fn fixture() -> PathBuf {
    repo_root().join("tests/fixtures/sim-povnav")
}

/// The fixture's graph with every node's config inline, as `edit` (node
/// name, config) leaves it, written into `ns`: what a test runs when it
/// changes a stage's config.
fn edited_graph(ns: &Namespace, edit: impl Fn(&str, &mut toml::Table)) -> PathBuf {
    let text = std::fs::read_to_string(fixture().join("graph.toml")).unwrap();
    let mut graph: toml::Table = toml::from_str(&text).unwrap();
    for node in graph["node"].as_array_mut().unwrap() {
        let node = node.as_table_mut().unwrap();
        let name = node["name"].as_str().unwrap().to_string();
        let file = fixture().join(node["config"].as_str().unwrap());
        let mut config: toml::Table =
            toml::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
        edit(&name, &mut config);
        node.insert("config".into(), toml::Value::Table(config));
    }
    ns.write("graph.toml", &toml::to_string(&graph).unwrap())
}

/// The servo's stale-input deadline set to `deadline_s` in `config`, the
/// servo's.
fn servo_deadline(config: &mut toml::Table, deadline_s: f64) {
    config.insert("subgoal_deadline_s".into(), toml::Value::Float(deadline_s));
}

fn replay_args<'a>(answers: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "replay",
        FIXTURE_RECORDING,
        "--topics",
        INPUTS,
        "--driving",
        "camera/front/image",
        "--answer",
        "perception/front/navigability,nav/subgoal,nav/path/visual,cmd/velocity",
        "--record-answers",
        answers.to_str().unwrap(),
    ];
    a.extend_from_slice(extra);
    a
}

/// Graph file `graph` (the fixture's, or an edited one) started through
/// `farsight run` (with extra environment), once every node said it is
/// ready.
fn run_graph(ns: &Namespace, graph: &Path, env: &[(&str, &str)]) -> Proc {
    ns.run_graph_file(graph, &STAGES, env)
}

/// Replays the fixture lock-step into the graph running in `ns`; returns
/// the recording of every answer.
fn lockstep_replay(ns: &Namespace) -> PathBuf {
    let answers = ns.root.join("answers.mcap");
    let mut replay = Proc::start("farsight", &replay_args(&answers, &["--lockstep"]), ns);
    let code = replay.wait_exit(Duration::from_secs(60));
    assert_eq!(code, Some(0), "{}", replay.stderr_so_far());
    answers
}

fn mismatches(run: &Path, topics: &[&str]) -> Vec<Mismatch> {
    let golden = Recording::open(&fixture().join("golden.mcap")).unwrap();
    let run = Recording::open(run).unwrap();
    let topics: Vec<String> = topics.iter().map(|s| s.to_string()).collect();
    compare(&golden, &run, &topics, Tolerance::default()).unwrap()
}

fn report(m: &[Mismatch]) -> String {
    m.iter().take(20).map(|m| format!("\n  {m}")).collect()
}

#[test]
fn a_lockstep_replay_through_the_real_stages_reproduces_every_golden_output() {
    let ns = Namespace::new("golden");
    let _graph = run_graph(&ns, &fixture().join("graph.toml"), &[]);
    let answers = lockstep_replay(&ns);
    let diffs = mismatches(&answers, &OUTPUTS);
    assert!(
        diffs.is_empty(),
        "{} differences:{}",
        diffs.len(),
        report(&diffs)
    );
    // Not vacuous: the run holds every frame of every output topic.
    let frames = input_frames();
    assert!(frames.len() > 70, "{frames:?}");
    let seen = frames_by_topic(&answers);
    for t in OUTPUTS {
        assert_eq!(seen.get(t), Some(&frames.iter().copied().collect()), "{t}");
    }
}

#[test]
fn a_changed_output_is_reported_with_topic_sequence_and_field() {
    // The same replay with the servo's gain changed must not pass: the diff
    // names cmd/velocity, the first frame that moved and the field.
    let ns = Namespace::new("goldenneg");
    let graph = edited_graph(&ns, |node, config| {
        if node != "velocity-servoing" {
            return;
        }
        let gains = config
            .entry("servo")
            .or_insert_with(|| toml::Value::Table(Default::default()))
            .as_table_mut()
            .unwrap();
        let k = gains.get("k_angular").and_then(toml::Value::as_float);
        assert_ne!(k, Some(1.2), "the fixture's gain is not the changed one");
        gains.insert("k_angular".into(), toml::Value::Float(1.2));
    });
    let _graph = run_graph(&ns, &graph, &[]);
    let answers = lockstep_replay(&ns);
    let diffs = mismatches(&answers, &OUTPUTS);
    assert!(!diffs.is_empty());
    assert!(
        diffs.iter().all(|d| d.topic == "cmd/velocity"),
        "{}",
        report(&diffs)
    );
    assert!(
        diffs.iter().any(|d| d.field == "angular_radps"),
        "{}",
        report(&diffs)
    );
    let first = diffs.iter().map(|d| d.seq).min().unwrap();
    assert!(input_frames().contains(&first), "{first}");
}

/// The sequence numbers of the fixture's camera frames.
fn input_frames() -> Vec<u64> {
    let mut out = Vec::new();
    Recording::open(&fixture().join("recording.mcap"))
        .unwrap()
        .for_each(|m| {
            if &*m.topic == "camera/front/image" {
                out.push(m.sequence as u64);
            }
            Ok(())
        })
        .unwrap();
    out
}

/// The frames each topic of a recording of answers carried (sequence 0,
/// the servo's stop before its first input, left out).
fn frames_by_topic(path: &Path) -> BTreeMap<String, BTreeSet<u64>> {
    let mut seen: BTreeMap<String, BTreeSet<u64>> = BTreeMap::new();
    Recording::open(path)
        .unwrap()
        .for_each(|m| {
            let d = farsight_recording::diff::decode(&m.topic, &m.data)?;
            let seq = d
                .fields
                .pointer("/stamp/frame_seq")
                .and_then(|v| v.as_u64());
            if let Some(s) = seq.filter(|&s| s > 0) {
                seen.entry(m.topic.to_string()).or_default().insert(s);
            }
            Ok(())
        })
        .unwrap();
    seen
}

/// The capture-time span of the fixture's camera frames, in seconds.
fn input_span_s() -> f64 {
    let (mut first, mut last) = (None, 0u64);
    Recording::open(&fixture().join("recording.mcap"))
        .unwrap()
        .for_each(|m| {
            if &*m.topic == "camera/front/image" {
                first.get_or_insert(m.capture_time_ns);
                last = last.max(m.capture_time_ns);
            }
            Ok(())
        })
        .unwrap();
    (last - first.unwrap()) as f64 * 1e-9
}

/// The commands of a run, by frame.
fn commands(path: &Path) -> Vec<VelocityCommand> {
    let mut out = Vec::new();
    Recording::open(path)
        .unwrap()
        .for_each(|m| {
            if &*m.topic == "cmd/velocity" {
                out.push(wire::decode_message::<VelocityCommand>(&m.data).unwrap());
            }
            Ok(())
        })
        .unwrap();
    out
}

#[test]
fn each_stage_killed_mid_replay_comes_back_and_matches_the_golden_run_again() {
    for (k, victim) in STAGES.iter().enumerate() {
        let ns = Namespace::new(&format!("restart{k}"));
        let graph = edited_graph(&ns, |node, config| {
            if node == "velocity-servoing" {
                servo_deadline(config, 0.3);
            }
        });
        let run = run_graph(&ns, &graph, &[]);
        let pids: Vec<u32> = STAGES
            .iter()
            .map(|s| {
                run.child_instance_pid(s)
                    .unwrap_or_else(|| panic!("no process for node {s}"))
            })
            .collect();
        let answers = ns.root.join("answers.mcap");
        let args = replay_args(&answers, &["--lockstep", "--timeout-s", "0.4"]);
        let bus = ns.bus("restart-test");
        let cmd = bus.subscriber(&topics::velocity_command()).unwrap();
        let mut replay = Proc::start("farsight", &args, &ns);
        // Frames go out every few milliseconds while the graph answers: let
        // 20 through, then SIGKILL the victim; `farsight run` restarts it
        // after its back-off (the replay waits 0.4 s per unanswered frame).
        let end = Instant::now() + Duration::from_secs(30);
        while cmd.latest().unwrap().is_none_or(|c| c.stamp.frame_seq < 20) {
            assert!(
                Instant::now() < end,
                "{victim}: the replay did not get going"
            );
            std::thread::sleep(Duration::from_micros(200));
        }
        let killed = std::process::Command::new("kill")
            .args(["-KILL", &pids[k].to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        let killed_at = Instant::now();
        for needle in [format!("{victim}: exited"), format!("{victim}: ready")] {
            assert!(
                run.wait_line(Duration::from_secs(60), |l| l.starts_with(&needle))
                    .is_some(),
                "farsight run never printed {needle:?}"
            );
        }
        let back_after = killed_at.elapsed();
        let code = replay.wait_exit(Duration::from_secs(90));
        let out = replay.stderr_so_far();
        // Frames the dead stage never answered are reported, not hidden:
        // the replay fails and says how many.
        assert_eq!(
            code,
            Some(1),
            "{victim}: the outage must be reported\n{out}"
        );
        assert!(
            out.contains("frames were not consumed by the graph"),
            "{out}"
        );
        // The others kept running all along, the victim is a new process.
        for (j, s) in STAGES.iter().enumerate() {
            let now = run.child_instance_pid(s);
            if j == k {
                assert!(now.is_some_and(|p| p != pids[k]), "{s} not restarted");
            } else {
                assert_eq!(now, Some(pids[j]), "{s} was restarted");
            }
        }
        let cmds = commands(&answers);
        if *victim != "velocity-servoing" {
            // Its input gone, the servo stopped the robot: zero velocity
            // with the stale-input reason, within its 0.3 s deadline.
            assert!(
                cmds.iter().any(|c| c.reason == CommandReason::STALE_INPUT
                    && c.linear_mps == 0.0
                    && c.angular_radps == 0.0),
                "{victim}: no stop while its output was missing"
            );
        }
        // From the first frame after the victim is back, its outputs (and
        // everything downstream) match the golden run again. The servo ramps
        // up from the stop, so its commands are compared over the last 20
        // frames, once its acceleration limit has caught up.
        let answered: Vec<u64> = cmds.iter().map(|c| c.stamp.frame_seq).collect();
        let frames = input_frames();
        let last_frame = *frames.last().unwrap();
        let missing: Vec<u64> = frames
            .iter()
            .copied()
            .filter(|s| !answered.contains(s))
            .collect();
        assert!(
            !missing.is_empty() && answered.contains(&last_frame),
            "{victim}: outage {missing:?}"
        );
        let back = missing.iter().max().unwrap() + 1;
        let after: Vec<Mismatch> = mismatches(&answers, &OUTPUTS[..3])
            .into_iter()
            .filter(|m| m.seq >= back)
            .collect();
        assert!(
            after.is_empty(),
            "{victim} (back after {back_after:?} at frame {back}):{}",
            report(&after)
        );
        let late: Vec<Mismatch> = mismatches(&answers, &OUTPUTS[3..])
            .into_iter()
            .filter(|m| m.seq + 20 > last_frame)
            .collect();
        assert!(
            late.is_empty(),
            "{victim}: commands of the last 20 frames:{}",
            report(&late)
        );
    }
}

/// A replay at the recorded pace (and four times it) keeps to that clock
/// and accounts for every frame: each is answered on every answer topic or
/// listed as not consumed, and the replay fails exactly when one is listed.
/// The answer topics are queued, so the replay's own count is exact. The
/// graph reads its camera latest-value, as on the robot: on a loaded
/// machine it may skip a frame, which is what the list is for; how fast
/// the graph keeps up is for `farsight bench`, not this test.
#[test]
fn replays_at_recorded_speed_and_four_times_account_for_every_frame() {
    let ns = Namespace::new("rate");
    let queues = OUTPUTS.map(|t| format!("{t}=64")).join(",");
    let env = [(QUEUES_ENV, queues.as_str())];
    let _graph = run_graph(&ns, &fixture().join("graph.toml"), &env);
    let frames: BTreeSet<u64> = input_frames().into_iter().collect();
    let span_s = input_span_s();
    assert!(span_s > 5.0, "{span_s}");
    for speed in [1.0, 4.0] {
        let answers = ns.root.join(format!("answers-{speed}.mcap"));
        let speed_arg = speed.to_string();
        let args = replay_args(&answers, &["--speed", &speed_arg]);
        let mut replay = Proc::start_env("farsight", &args, &ns, &env);
        let code = replay.wait_exit(Duration::from_secs(60));
        let lines: Vec<String> = std::iter::from_fn(|| {
            replay
                .wait_line(Duration::from_millis(100), |_| true)
                .map(|(_, l)| l)
        })
        .collect();
        let out = format!(
            "at {speed}x:\n{}\n{}",
            lines.join("\n"),
            replay.stderr_so_far()
        );
        // "frames answered: A of N[; not consumed: [k, ...]]"
        let summary = lines
            .iter()
            .find_map(|l| l.strip_prefix("frames answered: "))
            .unwrap_or_else(|| panic!("no summary {out}"));
        let (counts, listed) = summary
            .split_once("; not consumed: ")
            .unwrap_or((summary, "[]"));
        let (answered, of) = counts.split_once(" of ").unwrap();
        let listed: BTreeSet<u64> = listed
            .trim_matches(|c| c == '[' || c == ']')
            .split(", ")
            .filter(|s| !s.is_empty())
            .map(|s| s.parse().unwrap())
            .collect();
        assert_eq!(of.parse::<usize>().unwrap(), frames.len(), "{out}");
        assert_eq!(
            answered.parse::<usize>().unwrap() + listed.len(),
            frames.len(),
            "{out}"
        );
        assert_eq!(code, Some(if listed.is_empty() { 0 } else { 1 }), "{out}");
        // Every frame not listed is in the answers recording on each
        // answer topic; a listed one is missing from at least one.
        let seen = frames_by_topic(&answers);
        for &k in &frames {
            let on_all = OUTPUTS
                .iter()
                .all(|t| seen.get(*t).is_some_and(|s| s.contains(&k)));
            assert_eq!(on_all, !listed.contains(&k), "frame {k} {out}");
        }
        assert!(listed.len() < frames.len(), "nothing answered {out}");
        // The pace is the recorded clock's: the frames cannot all have
        // gone out sooner than their span at this speed.
        let wall_s: f64 = lines
            .iter()
            .find_map(|l| {
                l.strip_prefix("replayed ")?
                    .split(" in ")
                    .nth(1)?
                    .strip_suffix(" s")
            })
            .unwrap_or_else(|| panic!("no wall time {out}"))
            .parse()
            .unwrap();
        assert!(wall_s >= span_s / speed, "{wall_s} s {out}");
    }
}

/// What a file holds: per topic, its messages' capture times, in file
/// order, and whether it is truncated (no summary).
fn contents(path: &Path) -> (BTreeMap<String, Vec<u64>>, bool) {
    let rec = Recording::open(path).unwrap();
    let mut out: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    let cut = rec
        .for_each(|m| {
            out.entry(m.topic.to_string())
                .or_default()
                .push(m.capture_time_ns);
            Ok(())
        })
        .unwrap();
    (out, cut.is_some())
}

/// Every camera image of a recording is whole: it decodes and validates.
fn images_whole(path: &Path) -> usize {
    let (messages, _) = Recording::open(path).unwrap().messages().unwrap();
    let mut n = 0;
    for m in messages
        .iter()
        .filter(|m| &*m.topic == "camera/front/image")
    {
        let (h, d) = wire::split_slice::<farsight_interfaces::msg::ImageHeader>(&m.data).unwrap();
        h.validate(d.len()).unwrap();
        n += 1;
    }
    n
}

/// A recorder killed without a word (SIGKILL) loses at most its open chunk:
/// it closes chunks at 1 s or 1 MiB, and also while nothing new arrives
/// (`farsight_recording::write`). The test is paced on what the file holds,
/// never on sleeps:
/// - While the fixture replays, the file's bytes as they are, which is what
///   a SIGKILL at that moment leaves, read as a truncated recording whose
///   images are whole, and they grow: chunks reach the file long before the
///   recorder stops.
/// - Once the replay has ended nothing new arrives, and the recorder's last
///   chunk still reaches the file: the file comes to hold the last message
///   of every topic the replay sent (the newest one, which a latest-value
///   reader always gets), so every message the recorder wrote before them
///   is there too, chunks being written in order. Without the time bound
///   that chunk would stay in memory until a clean stop, and the wait would
///   time out (it is generous: the bound is 1 s).
/// - SIGKILLed then, the recorder has lost nothing: the file holds exactly
///   those messages, with no summary. It replays up to the cut, then exits 1
///   naming where the data ends.
#[test]
fn a_recorder_killed_mid_run_or_idle_loses_at_most_its_open_chunk() {
    let ns = Namespace::new("killrec");
    let file = ns.root.join("cut.mcap");
    let mut rec = Proc::start(
        "farsight",
        &[
            "record",
            "--topics",
            INPUTS,
            "--out",
            file.to_str().unwrap(),
        ],
        &ns,
    );
    rec.wait_line(Duration::from_secs(10), |l| l == "farsight-record ready")
        .expect("recorder ready");
    let fixture_file = fixture().join("recording.mcap");
    // The newest message of each input topic the replay sends.
    let inputs: Vec<&str> = INPUTS.split(',').collect();
    let newest = |c: &BTreeMap<String, Vec<u64>>| -> BTreeMap<String, u64> {
        c.iter()
            .filter(|(t, _)| inputs.contains(&t.as_str()))
            .map(|(t, times)| (t.clone(), times.iter().copied().max().unwrap_or(0)))
            .collect()
    };
    let sent = newest(&contents(&fixture_file).0);
    assert_eq!(sent.len(), inputs.len(), "{sent:?}");
    let mut replay = Proc::start(
        "farsight",
        &["replay", fixture_file.to_str().unwrap(), "--topics", INPUTS],
        &ns,
    );
    // What a SIGKILL now would leave.
    let snapshot = ns.root.join("snapshot.mcap");
    let on_disk = || {
        std::fs::copy(&file, &snapshot).unwrap();
        contents(&snapshot)
    };
    let deadline = Instant::now() + Duration::from_secs(60);
    let mid = loop {
        let (c, cut) = on_disk();
        let images = c.get("camera/front/image").map_or(0, Vec::len);
        if images >= 5 {
            assert!(cut, "a running recorder's file has no summary");
            break images;
        }
        assert!(
            Instant::now() < deadline,
            "{images} images on disk after 60 s of recording: {}",
            rec.stderr_so_far()
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(images_whole(&snapshot) >= mid);
    assert_eq!(replay.wait_exit(Duration::from_secs(60)), Some(0));
    // Idle: the last chunk reaches the file with nothing after it.
    let deadline = Instant::now() + Duration::from_secs(30);
    let before_kill = loop {
        let (c, cut) = on_disk();
        assert!(cut, "a running recorder's file has no summary");
        if newest(&c) == sent {
            break c;
        }
        assert!(
            Instant::now() < deadline,
            "30 s after the replay ended the file holds the newest of {:?}, the replay sent {sent:?}",
            newest(&c)
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    rec.kill();
    let (killed, cut) = contents(&file);
    assert!(cut, "no summary was written");
    assert_eq!(killed, before_kill, "the kill lost messages");
    let images = images_whole(&file);
    assert!(images >= mid, "{images} images");
    let info = Recording::open(&file).unwrap().info().unwrap();
    // Foxglove's channels ride along by default: images, poses, transforms.
    for t in ["/camera/front/image", "/state/pose", "/tf"] {
        assert!(info.topics.iter().any(|i| i.topic == t), "{t}: {info}");
    }
    // It replays up to the cut, then exits 1 naming where the data ends
    // (--allow-truncated would make that 0; tests/mcap_inputs.rs).
    let mut again = Proc::start(
        "farsight",
        &["replay", file.to_str().unwrap(), "--as-fast"],
        &ns,
    );
    let code = again.wait_exit(Duration::from_secs(30));
    let out: Vec<String> = std::iter::from_fn(|| {
        again
            .wait_line(Duration::from_millis(100), |_| true)
            .map(|(_, l)| l)
    })
    .collect();
    let err = again.stderr_to_end();
    assert_eq!(code, Some(1), "{out:?}\n{err}");
    let cut_at = info.truncated.as_ref().unwrap().offset;
    assert!(
        err.contains(&format!(
            "error: {}: truncated at byte {cut_at} of ",
            file.display()
        )),
        "{err}"
    );
    let want = format!("  {:<34} {:>8}", "camera/front/image", images);
    assert!(
        out.iter().any(|l| l.starts_with("replayed ")) && out.contains(&want),
        "{out:?}"
    );
}

#[test]
fn a_replay_publishes_selected_topics_under_new_names_and_refuses_a_bad_remap() {
    let ns = Namespace::new("remap");
    let bus = ns.bus("remap-test");
    let left = bus.slice_subscriber(&topics::camera_image("left")).unwrap();
    let front = bus
        .slice_subscriber(&topics::camera_image("front"))
        .unwrap();
    let mut replay = Proc::start(
        "farsight",
        &[
            "replay",
            FIXTURE_RECORDING,
            "--topics",
            "camera/front/image",
            "--remap",
            "camera/front/image=camera/left/image",
            "--speed",
            "2",
        ],
        &ns,
    );
    let (mut seqs, mut on_front) = (Vec::new(), 0);
    let end = Instant::now() + Duration::from_secs(20);
    while Instant::now() < end && seqs.len() < 10 {
        if let Some(s) = left.latest().unwrap() {
            seqs.push(s.header().stamp.frame_seq);
        }
        if front.latest().unwrap().is_some() {
            on_front += 1;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(
        replay.wait_exit(Duration::from_secs(20)),
        Some(0),
        "{}",
        replay.stderr_so_far()
    );
    assert!(
        seqs.len() >= 10 && seqs.windows(2).all(|w| w[0] < w[1]),
        "{seqs:?}"
    );
    assert_eq!(on_front, 0, "only the new name is published");

    let mut bad = Proc::start(
        "farsight",
        &[
            "replay",
            FIXTURE_RECORDING,
            "--remap",
            "camera/front/image=state/pose",
        ],
        &ns,
    );
    assert_eq!(bad.wait_exit(Duration::from_secs(20)), Some(1));
    let err = bad.stderr_so_far();
    assert!(
        err.contains("camera/front/image=state/pose") && err.contains("same kind"),
        "{err}"
    );
}

#[test]
fn a_laptop_records_what_the_bridge_exports_over_zenoh() {
    use farsight_tests::free_port;
    let ns = Namespace::new("zenohrec");
    let port = free_port();
    let bridge_cfg = ns.write(
        "bridge.toml",
        &format!(
            "robot = \"testbot\"\n[zenoh]\nmode = \"peer\"\nlisten = [\"tcp/127.0.0.1:{port}\"]\n\
             [[export]]\ntopic = \"state/pose\"\n\
             [[export]]\ntopic = \"camera/front/image\"\ndownsample = 4\ncompression = \"jpeg\"\n"
        ),
    );
    let _bridge = ns.start_bridge(&bridge_cfg);
    let file = ns.root.join("laptop.mcap");
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut rec = Proc::start(
        "farsight",
        &[
            "record",
            "--connect",
            &endpoint,
            "--robot",
            "testbot",
            "--topics",
            "state/pose,camera/**",
            "--out",
            file.to_str().unwrap(),
        ],
        &ns,
    );
    rec.wait_line(Duration::from_secs(20), |l| l == "farsight-record ready")
        .unwrap_or_else(|| panic!("recorder:\n{}", rec.stderr_so_far()));
    std::thread::sleep(Duration::from_millis(500));
    let mut replay = Proc::start(
        "farsight",
        &[
            "replay",
            FIXTURE_RECORDING,
            "--topics",
            "state/pose,camera/front/image",
            "--speed",
            "4",
        ],
        &ns,
    );
    assert_eq!(
        replay.wait_exit(Duration::from_secs(30)),
        Some(0),
        "{}",
        replay.stderr_so_far()
    );
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        rec.terminate(Duration::from_secs(10)),
        Some(0),
        "{}",
        rec.stderr_so_far()
    );
    let info = Recording::open(&file).unwrap().info().unwrap();
    assert!(
        info.truncated.is_none(),
        "SIGTERM finishes the file: {info}"
    );
    let count = |t: &str| {
        info.topics
            .iter()
            .find(|i| i.topic == t)
            .map_or(0, |i| i.count)
    };
    // The bridge forwards the newest message at its own pace: most frames,
    // every one with its stamp; the images as the bridge sent them.
    assert!(count("state/pose") > 40, "{info}");
    assert!(count("camera/front/image") > 20, "{info}");
    assert!(count("/camera/front/image") > 20, "{info}");
    let (messages, _) = Recording::open(&file).unwrap().messages().unwrap();
    let images: Vec<_> = messages
        .iter()
        .filter(|m| &*m.topic == "camera/front/image")
        .collect();
    let (h, _) =
        wire::split_slice::<farsight_interfaces::msg::ImageHeader>(&images[0].data).unwrap();
    assert_eq!(
        (h.width, h.height, h.encoding.name()),
        (160, 90, Some("jpeg"))
    );
    // Frame numbers and capture times travel with them (frame 1 is at 0 s).
    assert!(images.iter().all(|m| m.sequence > 0));
    assert!(images
        .windows(2)
        .all(|w| w[0].capture_time_ns < w[1].capture_time_ns));
}

#[test]
fn the_orfd_recording_made_over_zenoh_feeds_camera_ingest_and_twinlitenet() {
    // tests/fixtures/orfd: the six real ORFD frames as a laptop recorded
    // them from the bridge (half size, JPEG). camera-ingest plays the file,
    // paced by the inference stage's output, and TwinLiteNet marks the road.
    use farsight_interfaces::msg::PixelEncoding;
    use farsight_tests::{navigable_fraction, toml_string, ORFD_ROAD_AHEAD, ORFD_SKY};
    let ns = Namespace::new("orfdreplay");
    let root = repo_root();
    let inference_cfg = ns.write(
        "inference.toml",
        &format!(
            "camera = \"front\"\nmodel_config = {}\n",
            toml_string(
                &root
                    .join("deploy/models/twinlitenet.toml")
                    .display()
                    .to_string()
            )
        ),
    );
    let ingest_cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nsource = \"mcap\"\nfile = {}\ntopic = \"camera/front/image\"\n\
             pace_by = \"perception/front/navigability\"\n[cameras.model]\nname = \"front\"\n\
             width = 640\nheight = 360\nfx = 743.875\nfy = 735.53\ncx = 312.25\ncy = 188.0\n",
            toml_string(
                &root
                    .join("tests/fixtures/orfd/recording.mcap")
                    .display()
                    .to_string()
            )
        ),
    );
    let bus = ns.bus("orfd-replay-test");
    let nav = bus
        .slice_subscriber(&topics::navigability("front"))
        .unwrap();
    let run = ns.run_graph(
        &[
            ("inference", &inference_cfg),
            ("camera-ingest", &ingest_cfg),
        ],
        &[],
        &["perception/front/navigability"],
    );
    let mut seen = Vec::new();
    let end = Instant::now() + Duration::from_secs(60);
    while seen.len() < 6 && Instant::now() < end {
        if let Some(s) = nav.latest().unwrap() {
            let h = *s.header();
            assert_eq!(
                (h.width, h.height, h.encoding),
                (640, 360, PixelEncoding::MONO8)
            );
            let (w, hh) = (h.width as usize, h.height as usize);
            let road = navigable_fraction(s.data(), w, hh, ORFD_ROAD_AHEAD.0, ORFD_ROAD_AHEAD.1);
            let sky = navigable_fraction(s.data(), w, hh, ORFD_SKY.0, ORFD_SKY.1);
            assert!(
                road > 0.8 && sky < 0.02,
                "frame {}: road {road:.2}, sky {sky:.2}",
                h.stamp.frame_seq
            );
            // The recorded stamps come through: ORFD's own capture times.
            assert!(h.stamp.capture_time_ns / 1_000_000 >= 1_623_721_491_895);
            seen.push(h.stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(
        seen,
        vec![1, 2, 3, 4, 5, 6],
        "{}",
        ns.node_log("camera-ingest")
    );
    assert!(
        run.wait_line(Duration::from_secs(20), |l| l
            .starts_with("camera-ingest: exited (exit status: 0)"))
            .is_some(),
        "{}",
        ns.node_log("camera-ingest")
    );
}

#[test]
fn a_laptop_inspects_the_graph_over_zenoh_while_a_recording_drives_it() {
    use farsight_tests::free_port;
    let ns = Namespace::new("inspect");
    let _graph = run_graph(&ns, &fixture().join("graph.toml"), &[]);
    let port = free_port();
    let mut cfg = format!(
        "robot = \"bot\"\n[zenoh]\nmode = \"router\"\nlisten = [\"tcp/127.0.0.1:{port}\"]\n\
         [[export]]\ntopic = \"camera/front/image\"\ndownsample = 2\ncompression = \"jpeg\"\n\
         [[export]]\ntopic = \"perception/front/navigability\"\ndownsample = 2\ncompression = \"png\"\n"
    );
    for t in [
        "camera/front/info",
        "nav/subgoal",
        "nav/path/visual",
        "cmd/velocity",
        "health/inference",
        "health/subgoal-selection",
        "health/velocity-servoing",
    ] {
        cfg += &format!("[[export]]\ntopic = \"{t}\"\n");
    }
    let bridge_cfg = ns.write("bridge.toml", &cfg);
    let _bridge = ns.start_bridge(&bridge_cfg);
    let mut replay = Proc::start(
        "farsight",
        &[
            "replay",
            FIXTURE_RECORDING,
            "--topics",
            INPUTS,
            "--speed",
            "1",
        ],
        &ns,
    );
    std::thread::sleep(Duration::from_secs(1));
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let laptop = |args: &[&str]| -> String {
        let mut all = vec![
            "inspect",
            "--connect",
            &endpoint,
            "--robot",
            "bot",
            "--seconds",
            "2.5",
        ];
        all.extend_from_slice(args);
        let mut p = Proc::start("farsight", &all, &ns);
        let code = p.wait_exit(Duration::from_secs(30));
        let lines: Vec<String> = std::iter::from_fn(|| {
            p.wait_line(Duration::from_millis(200), |_| true)
                .map(|(_, l)| l)
        })
        .collect();
        assert_eq!(
            code,
            Some(0),
            "{all:?}\n{}\n{}",
            lines.join("\n"),
            p.stderr_so_far()
        );
        lines.join("\n")
    };
    let view = laptop(&[]);
    for stage in STAGES {
        assert!(
            view.lines()
                .any(|l| l.trim_start().starts_with(stage) && l.contains(" ok ")),
            "{stage} alive and ok:\n{view}"
        );
    }
    // Rates near the recording's 10 Hz.
    let rate = |topic: &str| -> f64 {
        let line = view
            .lines()
            .find(|l| l.trim_start().starts_with(topic))
            .unwrap();
        line.split_whitespace().nth(2).unwrap().parse().unwrap()
    };
    for t in ["cmd/velocity", "nav/subgoal", "camera/front/image"] {
        let r = rate(t);
        assert!((7.0..13.0).contains(&r), "{t} at {r} Hz:\n{view}");
    }
    let echo = laptop(&["echo", "nav/subgoal", "--count", "2"]);
    assert_eq!(
        echo.lines()
            .filter(|l| l.contains("proximity_lambda_px"))
            .count(),
        2,
        "{echo}"
    );
    let snap_dir = ns.root.join("snap");
    let snap = laptop(&["snapshot", "--out", snap_dir.to_str().unwrap()]);
    assert!(snap.contains("camera-front.png"), "{snap}");
    let (h, rgb) =
        farsight_imaging::decode_png(&std::fs::read(snap_dir.join("camera-front.png")).unwrap())
            .unwrap();
    assert_eq!(
        (h.width, h.height),
        (320, 180),
        "the bridge's half-size frame"
    );
    let count = |c: [u8; 3]| rgb.chunks(3).filter(|p| *p == c).count();
    assert!(count([255, 150, 0]) > 20, "the visual path is drawn");
    assert!(count([255, 0, 0]) > 5, "the subgoal is drawn");
    assert_eq!(replay.wait_exit(Duration::from_secs(30)), Some(0));
}
