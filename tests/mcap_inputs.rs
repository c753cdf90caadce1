//! MCAP inputs are verified (issue 17): a file that is not an MCAP file, a
//! damaged one (a bad chunk CRC) and a truncated one each end
//! `farsight record --info`, `farsight replay`, `farsight diff` and
//! camera-ingest's `mcap` source with a non-zero exit naming the file and
//! the byte offset; a file cut off mid-write still replays up to its last
//! complete chunk. The fixtures are written here, at run time, with the
//! project's own recorder, then damaged.

use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Pose, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::wire;
use farsight_recording::write::{ChunkBounds, RecordingWriter, WriterOptions};
use farsight_tests::{Namespace, Proc};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where each chunk starts and how long it is, from the file's summary.
fn chunks(bytes: &[u8]) -> Vec<(u64, u64)> {
    mcap::Summary::read(bytes)
        .unwrap()
        .expect("a finished file has a summary")
        .chunk_indexes
        .iter()
        .map(|c| (c.chunk_start_offset, c.chunk_length))
        .collect()
}

/// The project's recorder writing every message as its own chunk, so that
/// each message can be damaged or cut on its own (recorders close chunks
/// at 1 s or 1 MiB by default).
fn writer(path: &Path, zstd: bool) -> RecordingWriter {
    let opts = WriterOptions {
        foxglove: false,
        zstd,
        chunks: ChunkBounds::EVERY_MESSAGE,
    };
    RecordingWriter::create_with_options(path, &opts).unwrap()
}

/// `n` poses 100 ms apart (capture times from 1 s), one chunk each;
/// returns the file's bytes.
fn poses(path: &Path, n: u64, zstd: bool) -> Vec<u8> {
    let mut w = writer(path, zstd);
    for k in 1..=n {
        let t = 1_000_000_000 + k * 100_000_000;
        let pose = Pose {
            stamp: Stamp::new(k, t),
            position_m: [k as f64, 0.0, 0.0],
            ..Default::default()
        };
        w.write(
            "state/pose",
            pose.stamp,
            t,
            &wire::encode_message(&pose).unwrap(),
        )
        .unwrap();
    }
    w.finish().unwrap();
    std::fs::read(path).unwrap()
}

/// `n` 8x6 RGB camera frames 100 ms apart on `camera/front/image`, one
/// chunk each.
fn frames(path: &Path, n: u64) -> Vec<u8> {
    let mut w = writer(path, true);
    for k in 1..=n {
        let t = 1_000_000_000 + k * 100_000_000;
        let h = ImageHeader::packed(Stamp::new(k, t), 0, 8, 6, PixelEncoding::RGB8);
        let px = vec![k as u8 * 10; 8 * 6 * 3];
        w.write(
            "camera/front/image",
            h.stamp,
            t,
            &wire::encode_slice(&h, &px).unwrap(),
        )
        .unwrap();
    }
    w.finish().unwrap();
    std::fs::read(path).unwrap()
}

/// The damaged inputs made from a good file: (name, bytes, what the error
/// must say besides the path).
struct Bad {
    name: &'static str,
    path: PathBuf,
    says: String,
}

/// Not an MCAP file (empty, random bytes, text) and a bad chunk CRC, next
/// to `good` (an uncompressed recording: a flipped byte in a message
/// leaves the chunk whole but its CRC wrong).
fn damaged(dir: &Path, good: &[u8]) -> Vec<Bad> {
    let mut noise = Vec::with_capacity(4096);
    let mut x = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..4096 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        noise.push(x as u8);
    }
    let (at, len) = chunks(good)[2];
    let mut flipped = good.to_vec();
    // The last byte of the chunk: inside its last message's data.
    flipped[(at + len - 1) as usize] ^= 0x40;
    let text = b"topic,messages\nstate/pose,5\n".to_vec();
    [
        (
            "empty.mcap",
            Vec::new(),
            "not an MCAP file: it is empty (no MCAP magic at byte 0)".to_string(),
        ),
        (
            "random.mcap",
            noise,
            "not an MCAP file: no MCAP magic at byte 0".to_string(),
        ),
        (
            "text.mcap",
            text,
            "not an MCAP file: no MCAP magic at byte 0 (it starts \"topic,me\")".to_string(),
        ),
        (
            "crc.mcap",
            flipped,
            format!("bad chunk CRC at byte {at} (expected 0x"),
        ),
    ]
    .into_iter()
    .map(|(name, bytes, says)| {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        Bad { name, path, says }
    })
    .collect()
}

/// `good` cut in the middle of its last chunk, as a recorder killed
/// mid-write leaves it; returns the file and where its whole data ends.
fn cut(dir: &Path, good: &[u8]) -> (PathBuf, u64) {
    let (at, len) = *chunks(good).last().unwrap();
    let path = dir.join("cut.mcap");
    std::fs::write(&path, &good[..(at + len / 2) as usize]).unwrap();
    (path, at)
}

/// Runs `farsight ARGS` to its end: exit code, stdout, stderr.
fn farsight(ns: &Namespace, args: &[&str]) -> (Option<i32>, String, String) {
    let mut p = Proc::start("farsight", args, ns);
    let code = p.wait_exit(Duration::from_secs(60));
    let out: Vec<String> = std::iter::from_fn(|| {
        p.wait_line(Duration::from_millis(200), |_| true)
            .map(|(_, l)| l)
    })
    .collect();
    (code, out.join("\n"), p.stderr_to_end())
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn record_info_refuses_bad_files_and_reports_a_cut_one_with_its_offset() {
    let ns = Namespace::new("mcapinfo");
    let good_path = ns.root.join("good.mcap");
    let good = poses(&good_path, 5, false);
    let (code, out, err) = farsight(&ns, &["record", "--info", s(&good_path)]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(out.contains("1 topics, 5 messages"), "{out}");
    for bad in damaged(&ns.root, &good) {
        let (code, out, err) = farsight(&ns, &["record", "--info", s(&bad.path)]);
        assert_eq!(code, Some(1), "{}: {out}\n{err}", bad.name);
        assert!(
            err.contains(&format!("error: {}: {}", bad.path.display(), bad.says)),
            "{}: {err}",
            bad.name
        );
    }
    // Cut mid-chunk: what is whole is listed, then a non-zero exit naming
    // where the whole data ends.
    let (path, at) = cut(&ns.root, &poses(&good_path, 5, true));
    let (code, out, err) = farsight(&ns, &["record", "--info", s(&path)]);
    assert_eq!(code, Some(1), "{out}\n{err}");
    assert!(out.contains("1 topics, 4 messages"), "{out}");
    let says = format!("{}: truncated at byte {at} of ", path.display());
    assert!(out.contains(&says), "{out}");
    assert!(
        err.contains(&format!("error: {says}"))
            && err.contains("the chunk record there needs")
            && err.contains("the 4 messages before it are whole"),
        "{err}"
    );
}

#[test]
fn replay_refuses_bad_files_and_plays_a_cut_one_to_its_last_chunk() {
    let ns = Namespace::new("mcapreplay");
    let good_path = ns.root.join("good.mcap");
    let good = poses(&good_path, 5, false);
    for bad in damaged(&ns.root, &good) {
        let (code, out, err) = farsight(&ns, &["replay", s(&bad.path), "--as-fast"]);
        assert_eq!(code, Some(1), "{}: {out}\n{err}", bad.name);
        assert!(
            err.contains(&format!("error: {}: {}", bad.path.display(), bad.says)),
            "{}: {err}",
            bad.name
        );
        // Refused before anything went out.
        assert!(!out.contains("replayed"), "{}: {out}", bad.name);
    }
    // The cut file: its four whole poses go out, at the recorded pace, then
    // the replay exits 1 naming where the data ends.
    let (path, at) = cut(&ns.root, &poses(&good_path, 5, true));
    let bus = ns.bus("mcap-replay-test");
    let sub = bus.subscriber(&topics::pose()).unwrap();
    let mut replay = Proc::start("farsight", &["replay", s(&path)], &ns);
    let mut seen = Vec::new();
    let end = Instant::now() + Duration::from_secs(20);
    while Instant::now() < end && replay.wait_exit(Duration::ZERO).is_none() {
        if let Some(p) = sub.latest().unwrap() {
            seen.push(p.stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    if let Some(p) = sub.latest().unwrap() {
        seen.push(p.stamp.frame_seq);
    }
    assert_eq!(seen, vec![1, 2, 3, 4]);
    let (code, out, err) = farsight(&ns, &["replay", s(&path), "--as-fast"]);
    assert_eq!(code, Some(1), "{out}\n{err}");
    assert!(out.contains("replayed 4 messages on 1 topics"), "{out}");
    assert!(
        err.contains(&format!(
            "error: {}: truncated at byte {at} of ",
            path.display()
        )) && err.contains("--allow-truncated"),
        "{err}"
    );
    // Accepting a cut recording: the same four, exit 0, the cut still said.
    let (code, out, err) = farsight(&ns, &["replay", s(&path), "--as-fast", "--allow-truncated"]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(
        out.contains("replayed 4 messages on 1 topics")
            && out.contains(&format!("truncated at byte {at}")),
        "{out}"
    );
}

#[test]
fn diff_refuses_bad_and_cut_files_on_either_side() {
    let ns = Namespace::new("mcapdiff");
    let good_path = ns.root.join("good.mcap");
    let good = poses(&good_path, 5, false);
    let (code, out, err) = farsight(&ns, &["diff", s(&good_path), s(&good_path)]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(out.contains("no differences"), "{out}");
    let (cut_path, at) = cut(&ns.root, &poses(&ns.root.join("zstd.mcap"), 5, true));
    let mut bads: Vec<(PathBuf, String)> = damaged(&ns.root, &good)
        .into_iter()
        .map(|b| (b.path, b.says))
        .collect();
    bads.push((cut_path, format!("truncated at byte {at} of ")));
    for (path, says) in &bads {
        for args in [[s(&good_path), s(path)], [s(path), s(&good_path)]] {
            let (code, out, err) = farsight(&ns, &["diff", args[0], args[1]]);
            assert_eq!(code, Some(1), "{args:?}: {out}\n{err}");
            assert!(
                err.contains(&format!("error: {}: {says}", path.display())),
                "{args:?}: {err}"
            );
        }
    }
}

fn ingest_config(ns: &Namespace, file: &str) -> PathBuf {
    ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nsource = \"mcap\"\nfile = \"{file}\"\ntopic = \"camera/front/image\"\n\
             [cameras.model]\nname = \"front\"\nwidth = 8\nheight = 6\nfx = 6.4\nfy = 6.4\ncx = 4.0\ncy = 3.0\n"
        ),
    )
}

#[test]
fn camera_ingest_refuses_bad_files_at_start_and_plays_a_cut_one_then_fails() {
    let ns = Namespace::new("mcapingest");
    let good_path = ns.root.join("good.mcap");
    // Uncompressed, so the flipped byte is a CRC error.
    let mut w = writer(&good_path, false);
    for k in 1..=5u64 {
        let h = ImageHeader::packed(Stamp::new(k, k * 1000), 0, 8, 6, PixelEncoding::RGB8);
        w.write(
            "camera/front/image",
            h.stamp,
            k * 1000,
            &wire::encode_slice(&h, &[7u8; 8 * 6 * 3]).unwrap(),
        )
        .unwrap();
    }
    w.finish().unwrap();
    let good = std::fs::read(&good_path).unwrap();
    for bad in damaged(&ns.root, &good) {
        let cfg = ingest_config(&ns, bad.name);
        let err = ns.start_must_fail("farsight-camera-ingest", &cfg);
        assert!(
            err.contains(&format!(
                "camera front: {}: {}",
                bad.path.display(),
                bad.says
            )),
            "{}: {err}",
            bad.name
        );
        assert!(!err.contains("panicked"), "{err}");
    }
    // Cut mid-chunk: ready, degraded, the four whole frames go out at their
    // recorded pace, then it exits 1 naming the cut.
    let (path, at) = cut(&ns.root, &frames(&good_path, 5));
    let cfg = ingest_config(&ns, "cut.mcap");
    let bus = ns.bus("mcap-ingest-test");
    let sub = bus
        .slice_subscriber(&topics::camera_image("front"))
        .unwrap();
    let mut stage = ns.start_stage("farsight-camera-ingest", "camera-ingest", &cfg);
    let mut seen = Vec::new();
    let end = Instant::now() + Duration::from_secs(20);
    let mut code = None;
    while Instant::now() < end && code.is_none() {
        if let Some(f) = sub.latest().unwrap() {
            seen.push((f.header().stamp.capture_time_ns, f.data()[0]));
        }
        code = stage.wait_exit(Duration::ZERO);
        std::thread::sleep(Duration::from_millis(2));
    }
    if let Some(f) = sub.latest().unwrap() {
        seen.push((f.header().stamp.capture_time_ns, f.data()[0]));
    }
    let err = stage.stderr_to_end();
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(
        seen,
        (1..=4u64)
            .map(|k| (1_000_000_000 + k * 100_000_000, k as u8 * 10))
            .collect::<Vec<_>>(),
        "{err}"
    );
    let says = format!("{}: truncated at byte {at} of ", path.display());
    assert!(
        err.contains(&says) && err.contains("published 4 frames before the cut"),
        "{err}"
    );
    assert!(
        err.contains(&format!("cut.mcap truncated at byte {at}")),
        "health: {err}"
    );
}
