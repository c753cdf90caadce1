//! The deployment in `deploy/`: systemd units that `systemd-analyze verify`
//! accepts, units that keep the stages independent and iceoryx2's files
//! visible to all of them, an installer that stages, keeps a user's configs
//! and changes nothing in a dry run, and shipped stage configs the stages
//! accept.

use farsight_tests::{bin, free_port, repo_root, Namespace, Proc};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

const STAGES: [&str; 8] = [
    "camera-ingest",
    "inference",
    "bin-projection",
    "costmap-fusion",
    "subgoal-selection",
    "velocity-servoing",
    "command-mux",
    "bridge",
];

/// `deploy/install.sh` staged under a fresh folder with the built binaries
/// (no models, no ONNX Runtime: those are copied files, not under test).
fn stage(ns: &Namespace, extra: &[&str]) -> (PathBuf, String) {
    let prefix = ns.root.join("stage");
    let empty = ns.root.join("no-models");
    std::fs::create_dir_all(&empty).unwrap();
    let out = Command::new(repo_root().join("deploy/install.sh"))
        .arg("--prefix")
        .arg(&prefix)
        .arg("--bin-dir")
        .arg(bin("farsight").parent().unwrap())
        .arg("--models")
        .arg(&empty)
        .args(["--ort-lib", "/nonexistent"])
        .args(extra)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (prefix, text)
}

fn units(dir: &Path) -> Vec<PathBuf> {
    let mut u: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    u.sort();
    u
}

/// `systemd-analyze verify` on copies of `units` whose ExecStart points at
/// `bin_dir` (verify checks that the command exists). Any output is a
/// finding: verify exits 0 on a key it ignores.
fn verify(units: &[PathBuf], bin_dir: &Path, into: &Path) -> (bool, String) {
    std::fs::create_dir_all(into).unwrap();
    let mut copies = Vec::new();
    for u in units {
        let text = std::fs::read_to_string(u).unwrap().replace(
            "ExecStart=/usr/local/bin/",
            &format!("ExecStart={}/", bin_dir.display()),
        );
        let c = into.join(u.file_name().unwrap());
        std::fs::write(&c, text).unwrap();
        copies.push(c);
    }
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .args(&copies)
        .output()
        .expect("systemd-analyze (Debian's systemd package) must be installed");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success() && text.trim().is_empty(), text)
}

#[test]
fn every_unit_passes_systemd_analyze_verify() {
    let ns = Namespace::new("verify");
    let (prefix, _) = stage(&ns, &[]);
    let installed = units(&prefix.join("etc/systemd/system"));
    assert_eq!(installed.len(), STAGES.len() + 1, "{installed:?}");
    let (ok, text) = verify(
        &installed,
        &prefix.join("usr/local/bin"),
        &ns.root.join("verify"),
    );
    assert!(ok, "systemd-analyze verify:\n{text}");

    // The check can fail: a misspelt restart policy is reported.
    let broken = ns.root.join("broken/farsight-inference.service");
    std::fs::create_dir_all(broken.parent().unwrap()).unwrap();
    let text =
        std::fs::read_to_string(prefix.join("etc/systemd/system/farsight-inference.service"))
            .unwrap()
            .replace("Restart=always", "Restart=allways");
    std::fs::write(&broken, text).unwrap();
    let (ok, text) = verify(
        &[broken],
        &prefix.join("usr/local/bin"),
        &ns.root.join("v2"),
    );
    assert!(!ok && text.contains("allways"), "{text}");
}

#[test]
fn the_units_keep_stages_independent_and_iceoryx2_visible_to_all() {
    let dir = repo_root().join("deploy/systemd");
    let target = std::fs::read_to_string(dir.join("farsight.target")).unwrap();
    for s in STAGES {
        let unit = std::fs::read_to_string(dir.join(format!("farsight-{s}.service"))).unwrap();
        let has = |line: &str| unit.lines().any(|l| l.trim() == line);
        for line in [
            "Restart=always",
            "RemoveIPC=no",
            "PrivateTmp=no",
            "User=farsight",
            "PartOf=farsight.target",
            "WantedBy=farsight.target",
            "Environment=FARSIGHT_IPC_ROOT=/run/farsight/iceoryx2/",
        ] {
            assert!(has(line), "farsight-{s}.service lacks {line}");
        }
        assert!(
            has(&format!(
                "ExecStart=/usr/local/bin/farsight-{s} --config /etc/farsight/{s}.toml"
            )),
            "{s}"
        );
        // A restart of one stage pulls no other stage with it.
        for l in unit.lines().filter(|l| {
            l.starts_with("Requires=") || l.starts_with("BindsTo=") || l.starts_with("Wants=")
        }) {
            assert!(!l.contains("farsight-"), "farsight-{s}.service: {l}");
        }
        assert!(target.contains(&format!("farsight-{s}.service")), "{s}");
    }
    let tmpfiles =
        std::fs::read_to_string(repo_root().join("deploy/tmpfiles.d/farsight.conf")).unwrap();
    assert!(tmpfiles.contains("d /run/farsight/iceoryx2 0750 farsight farsight"));
}

#[test]
fn a_dry_run_changes_nothing_and_a_reinstall_keeps_the_users_configs() {
    let ns = Namespace::new("install");
    let (prefix, text) = stage(&ns, &["--dry-run"]);
    assert!(!prefix.exists(), "a dry run created {}", prefix.display());
    assert!(text.contains("install: install -m 0755"), "{text}");
    assert!(text.contains("farsight.target"), "{text}");

    let (prefix, _) = stage(&ns, &[]);
    let servo = prefix.join("etc/farsight/velocity-servoing.toml");
    std::fs::write(&servo, "output_rate_hz = 50.0\n").unwrap();
    let (_, text) = stage(&ns, &[]);
    assert_eq!(
        std::fs::read_to_string(&servo).unwrap(),
        "output_rate_hz = 50.0\n"
    );
    assert!(prefix
        .join("etc/farsight/velocity-servoing.toml.new")
        .exists());
    assert!(text.contains("kept your"), "{text}");
    let model =
        std::fs::read_to_string(prefix.join("etc/farsight/models/twinlitenet.toml")).unwrap();
    assert!(
        model.contains("model = \"/usr/local/share/farsight/models/twinlitenet/best.onnx\""),
        "{model}"
    );

    let out = Command::new(repo_root().join("deploy/uninstall.sh"))
        .arg("--prefix")
        .arg(&prefix)
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(!prefix.join("usr/local/bin/farsight-inference").exists());
    assert!(!prefix.join("etc/systemd/system/farsight.target").exists());
    assert!(servo.exists(), "configs stay without --purge");
}

#[test]
fn the_shipped_configs_start_their_stages() {
    let ns = Namespace::new("shipped");
    let (prefix, _) = stage(&ns, &[]);
    let etc = prefix.join("etc/farsight");
    // Port 7447 may be taken on a test machine: the router listens
    // elsewhere, with the staged users file.
    let router = std::fs::read_to_string(etc.join("zenoh/robot.json5"))
        .unwrap()
        .replace(
            "tcp/0.0.0.0:7447",
            &format!("tcp/127.0.0.1:{}", free_port()),
        )
        .replace(
            "/etc/farsight/zenoh/users.txt",
            etc.join("zenoh/users.txt").to_str().unwrap(),
        );
    std::fs::write(etc.join("zenoh/robot.json5"), router).unwrap();
    let mut running: Vec<Proc> = Vec::new();
    for s in [
        "bin-projection",
        "costmap-fusion",
        "subgoal-selection",
        "velocity-servoing",
        "command-mux",
        "bridge",
    ] {
        running.push(ns.start_stage(&format!("farsight-{s}"), s, &etc.join(format!("{s}.toml"))));
    }
    // These two read the config and then need what only the robot has: the
    // installed model, the camera. They stop saying which.
    let err = ns.start_must_fail("farsight-inference", &etc.join("inference.toml"));
    assert!(
        err.contains("/usr/local/share/farsight/models/twinlitenet/best.onnx"),
        "{err}"
    );
    let err = ns.start_must_fail("farsight-camera-ingest", &etc.join("camera-ingest.toml"));
    assert!(err.contains("/dev/video0"), "{err}");
    for mut p in running {
        assert_eq!(p.terminate(Duration::from_secs(10)), Some(0), "{}", p.name);
    }
}

#[test]
fn the_robots_router_lets_laptops_read_and_only_operators_command() {
    use farsight_interfaces::topics;
    let ns = Namespace::new("acl");
    let port = free_port();
    // The shipped router config and users, pointed at this test's port and files.
    let users = ns.write(
        "users.txt",
        &std::fs::read_to_string(repo_root().join("deploy/zenoh/users.txt")).unwrap(),
    );
    let router = std::fs::read_to_string(repo_root().join("deploy/zenoh/robot.json5"))
        .unwrap()
        .replace("tcp/0.0.0.0:7447", &format!("tcp/127.0.0.1:{port}"))
        .replace("/etc/farsight/zenoh/users.txt", users.to_str().unwrap());
    let router = ns.write("robot.json5", &router);
    let bridge_cfg = ns.write(
        "bridge.toml",
        &format!(
            "robot = \"robot\"\n[zenoh]\nconfig_file = {:?}\n\
             [[export]]\ntopic = \"health/bridge\"\n[[import]]\ntopic = \"nav/goal\"\n",
            router.to_str().unwrap()
        ),
    );
    let bus = ns.bus("acl-test");
    let goals = bus.subscriber(&topics::goal()).unwrap();
    let _bridge = ns.start_bridge(&bridge_cfg);
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let as_user = |user: &str, password: &str, args: &[&str]| {
        Proc::farsight_as(None, &ns, user, password, args)
    };
    let publish = [
        "probe",
        "net-publish-nav",
        "--connect",
        &endpoint,
        "--robot",
        "robot",
        "--duration-s",
        "1.5",
    ];
    // A laptop reads the graph...
    let inspect = [
        "inspect",
        "--connect",
        &endpoint,
        "--robot",
        "robot",
        "--seconds",
        "2.5",
    ];
    let (code, view) = as_user("laptop", "laptop-secret", &inspect);
    assert_eq!(code, Some(0), "{view}");
    assert!(view.contains("bridge"), "{view}");
    // ...but its goals never reach the robot.
    let (code, out) = as_user("laptop", "laptop-secret", &publish);
    assert_eq!(code, Some(0), "{out}");
    assert!(
        goals.latest().unwrap().is_none(),
        "a laptop without operator rights set a goal"
    );
    // The operator's do.
    let (code, out) = as_user("operator", "operator-secret", &publish);
    assert_eq!(code, Some(0), "{out}");
    let goal = goals
        .latest()
        .unwrap()
        .expect("the operator's goal arrives");
    assert!(goal.x_m.is_finite());
    // A wrong password gets nothing at all.
    let (code, out) = as_user("laptop", "guess", &inspect);
    assert_ne!(code, Some(0), "{out}");
}
