//! The deployment in `deploy/`: systemd units that `systemd-analyze verify`
//! accepts, units that keep the stages independent and iceoryx2's files
//! visible to all of them, an installer that stages, keeps a user's configs
//! and changes nothing in a dry run, and shipped stage configs the stages
//! accept; a router whose generated ACL lets laptops read and write
//! nothing; and an install whose bridge and stages run as user `farsight`.

use farsight_interfaces::transport::net::NetBus;
use farsight_tests::{bin, free_port, repo_root, toml_string, Namespace, Proc};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use zenoh::Wait;

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
    // The IJG licence of jpeg-encoder asks for its notice beside the binaries.
    let notice =
        std::fs::read_to_string(prefix.join("usr/local/share/doc/farsight/NOTICE")).unwrap();
    assert!(notice.contains("Independent JPEG Group"), "{notice}");
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

/// A zenoh client of the robot's router at `endpoint`, logged in as `user`.
fn login(endpoint: &str, user: &str, password: &str) -> NetBus {
    let config = NetBus::config("client", &[], &[endpoint.to_string()]).unwrap();
    let config = NetBus::with_credentials(config, user, password).unwrap();
    NetBus::open(config, "robot").unwrap_or_else(|e| panic!("{user} logs in: {e}"))
}

/// Puts `payload` on `key` every 50 ms for `seconds` (a put made before the
/// router told the client about the subscribers would not be sent at all).
fn keep_putting(net: &NetBus, key: &str, payload: &str, seconds: f64) {
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    while Instant::now() < end {
        net.session().put(key, payload).wait().unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The keys of the live tokens under `farsight/robot/alive/**`, as `net` sees them.
fn alive(net: &NetBus) -> Vec<String> {
    let replies = net
        .session()
        .liveliness()
        .get("farsight/robot/alive/**")
        .timeout(Duration::from_secs(2))
        .wait()
        .unwrap();
    let mut keys = Vec::new();
    while let Ok(r) = replies.recv() {
        if let Ok(sample) = r.result() {
            keys.push(sample.key_expr().as_str().to_string());
        }
    }
    keys.sort();
    keys
}

/// The robot's router, its config generated by `farsight-bridge
/// --print-router-config` from a bridge that imports only `nav/goal`: a
/// laptop reads but writes nothing (no put, no liveliness token, no fake
/// health); the operator puts on the imported key and nowhere else.
#[test]
fn the_robots_router_lets_laptops_read_and_only_operators_command() {
    use farsight_interfaces::fixed::FixedStr;
    use farsight_interfaces::msg::{HealthState, StageHealth};
    use farsight_interfaces::topics;
    let ns = Namespace::new("acl");
    let port = free_port();
    let users = ns.write(
        "users.txt",
        &std::fs::read_to_string(repo_root().join("deploy/zenoh/users.txt")).unwrap(),
    );
    let router = ns.root.join("robot.json5");
    let bridge_cfg = ns.write(
        "bridge.toml",
        &format!(
            "robot = \"robot\"\n[zenoh]\nconfig_file = {}\n\
             [[export]]\ntopic = \"health/bridge\"\n[[import]]\ntopic = \"nav/goal\"\n",
            toml_string(router.to_str().unwrap())
        ),
    );
    // The router config as install.sh writes it, pointed at this test's port and users.
    let out = Command::new(bin("farsight-bridge"))
        .arg("--config")
        .arg(&bridge_cfg)
        .arg("--print-router-config")
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let generated = String::from_utf8(out.stdout).unwrap();
    assert!(
        generated.contains("\"farsight/robot/nav/goal\""),
        "{generated}"
    );
    assert!(!generated.contains("safety/estop"), "{generated}");
    std::fs::write(
        &router,
        generated
            .replace("tcp/0.0.0.0:7447", &format!("tcp/127.0.0.1:{port}"))
            .replace("/etc/farsight/zenoh/users.txt", users.to_str().unwrap()),
    )
    .unwrap();
    let bus = ns.bus("acl-test");
    let goals = bus.subscriber(&topics::goal()).unwrap();
    let bridge = ns.start_bridge(&bridge_cfg);
    let endpoint = format!("tcp/127.0.0.1:{port}");

    // Everything the router passes on under farsight/robot/**, as a laptop hears it.
    let watcher = login(&endpoint, "laptop", "laptop-secret");
    let heard = watcher
        .session()
        .declare_subscriber("farsight/robot/**")
        .wait()
        .unwrap();
    let laptop = login(&endpoint, "laptop", "laptop-secret");
    let operator = login(&endpoint, "operator", "operator-secret");

    // Liveliness: the bridge's token is listed; one a laptop (or the
    // operator) declares is refused by the router, so nobody lists it.
    let _ghost = laptop
        .session()
        .liveliness()
        .declare_token("farsight/robot/alive/ghost")
        .wait()
        .unwrap();
    let _ghost2 = operator
        .session()
        .liveliness()
        .declare_token("farsight/robot/alive/ghost-operator")
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(alive(&watcher), ["farsight/robot/alive/bridge"]);

    // Puts: only the operator's on the imported key get through. Meanwhile
    // the laptop sends a health report of a stage that does not exist,
    // which `farsight inspect` would list if the router let it through.
    let endpoint = endpoint.as_str();
    let inspect = [
        "inspect",
        "--connect",
        endpoint,
        "--robot",
        "robot",
        "--seconds",
        "2.5",
    ];
    let view = std::thread::scope(|s| {
        s.spawn(|| {
            let mut fake = laptop.publisher(&topics::health("ghost")).unwrap();
            let end = Instant::now() + Duration::from_secs(4);
            while Instant::now() < end {
                fake.publish(&StageHealth {
                    stamp: farsight_tests::stamp_now(1),
                    stage: FixedStr::new("ghost").unwrap(),
                    state: HealthState::OK,
                    ..Default::default()
                })
                .unwrap();
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        s.spawn(|| {
            keep_putting(
                &laptop,
                "farsight/robot/nav/goal",
                "laptop on nav/goal",
                2.0,
            )
        });
        s.spawn(|| {
            keep_putting(
                &operator,
                "farsight/robot/state/pose",
                "operator on state/pose",
                2.0,
            )
        });
        s.spawn(|| {
            keep_putting(
                &operator,
                "farsight/other/nav/goal",
                "operator on another robot",
                2.0,
            )
        });
        s.spawn(|| {
            let end = Instant::now() + Duration::from_secs(2);
            while Instant::now() < end {
                operator
                    .session()
                    .delete("farsight/robot/nav/goal")
                    .wait()
                    .unwrap();
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        s.spawn(|| {
            keep_putting(
                &operator,
                "farsight/robot/nav/goal",
                "operator on nav/goal",
                2.0,
            )
        });
        // A laptop reads the graph (the bridge's health), and sees no ghost.
        Proc::farsight_as(None, &ns, "laptop", "laptop-secret", &inspect)
    });
    assert_eq!(view.0, Some(0), "{}", view.1);
    assert!(view.1.contains("bridge"), "{}", view.1);
    assert!(!view.1.contains("ghost"), "{}", view.1);
    std::thread::sleep(Duration::from_millis(300));
    let mut got: Vec<String> = Vec::new();
    while let Ok(Some(sample)) = heard.try_recv() {
        let what = match sample.kind() {
            zenoh::sample::SampleKind::Delete => format!("delete {}", sample.key_expr()),
            zenoh::sample::SampleKind::Put if sample.key_expr().as_str().contains("/health/") => {
                sample.key_expr().to_string()
            }
            zenoh::sample::SampleKind::Put => {
                String::from_utf8_lossy(&sample.payload().to_bytes()).to_string()
            }
        };
        if !got.contains(&what) {
            got.push(what);
        }
    }
    assert!(
        got.iter().any(|g| g == "operator on nav/goal"),
        "the operator's put on the imported key did not pass: {got:?}"
    );
    assert!(
        got.iter().any(|g| g == "farsight/robot/health/bridge"),
        "the bridge's health did not reach the laptop: {got:?}"
    );
    for refused in [
        "laptop on nav/goal",
        "operator on state/pose",
        "operator on another robot",
        "delete farsight/robot/nav/goal",
        "farsight/robot/health/ghost",
    ] {
        assert!(
            !got.iter().any(|g| g == refused),
            "the router passed {refused:?}: {got:?}"
        );
    }
    // The operator's raw puts on nav/goal were no goals: the bridge dropped them.
    assert!(goals.latest().unwrap().is_none());

    let as_user = |user: &str, password: &str, args: &[&str]| {
        Proc::farsight_as(None, &ns, user, password, args)
    };
    let publish = [
        "probe",
        "net-publish-nav",
        "--connect",
        endpoint,
        "--robot",
        "robot",
        "--duration-s",
        "1.5",
    ];
    // A laptop's goals never reach the robot.
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
    // The bridge loaded the ACL its imports imply: no warning.
    let log = bridge.stderr_so_far();
    assert!(!log.contains("access_control"), "{log}");
}

/// The `farsight` service user and group, created (as a system user, no
/// home, no login) when this machine lacks them; the test runs as root, as
/// in the sandbox and CI. Returns its uid and gid.
fn farsight_user() -> (u32, u32) {
    let id = |flag: &str| {
        Command::new("id")
            .args([flag, "farsight"])
            .output()
            .ok()
            .filter(|o| o.status.success())
            .and_then(|o| {
                String::from_utf8_lossy(&o.stdout)
                    .trim()
                    .parse::<u32>()
                    .ok()
            })
    };
    if id("-u").is_none() {
        eprintln!("no user farsight on this machine: creating it (useradd --system)");
        let out = Command::new("useradd")
            .args([
                "--system",
                "--user-group",
                "--no-create-home",
                "--home-dir",
                "/var/lib/farsight",
                "--shell",
                "/usr/sbin/nologin",
                "farsight",
            ])
            .output()
            .expect("useradd (Debian's passwd package)");
        // Another test process may have created it meanwhile (exit 9: exists).
        assert!(
            out.status.success() || out.status.code() == Some(9),
            "useradd farsight: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    (id("-u").unwrap(), id("-g").unwrap())
}

/// What systemd would run for `unit` as installed under `prefix`: its
/// ExecStart, as its User and Group (setpriv), with its Environment and
/// nothing else of the caller's, every installed path moved under
/// `prefix` (`/run/farsight` to `run`). Only systemd itself is missing
/// (no sandboxing, no NOTIFY_SOCKET). `FARSIGHT_IPC_PREFIX` keeps the
/// test's namespace.
fn as_unit(ns: &Namespace, prefix: &Path, run: &Path, unit: &str) -> Command {
    let text = std::fs::read_to_string(prefix.join("etc/systemd/system").join(unit)).unwrap();
    let p = prefix.display().to_string();
    let moved = |s: &str| {
        s.replace("/usr/local/", &format!("{p}/usr/local/"))
            .replace("/etc/farsight/", &format!("{p}/etc/farsight/"))
            .replace("/run/farsight/", &format!("{}/", run.display()))
    };
    let key = |k: &str| -> Vec<String> {
        text.lines()
            .filter_map(|l| l.strip_prefix(&format!("{k}=")))
            .map(moved)
            .collect()
    };
    let (user, group) = (&key("User")[0], &key("Group")[0]);
    let exec = &key("ExecStart")[0];
    let mut cmd = Command::new("setpriv");
    cmd.arg(format!("--reuid={user}"))
        .arg(format!("--regid={group}"))
        .arg("--init-groups")
        .arg("--")
        .args(exec.split_whitespace())
        .env_clear()
        .env("PATH", "/usr/local/bin:/usr/bin:/bin")
        .env("USER", user)
        .env("LOGNAME", user)
        .env("HOME", "/var/lib/farsight")
        .env("FARSIGHT_IPC_PREFIX", &ns.prefix)
        .env("RUST_LOG", "info");
    for e in key("Environment") {
        let (k, v) = e.split_once('=').unwrap();
        cmd.env(k, v);
    }
    cmd
}

/// Installed means runnable: `install.sh` into a prefix, the tmpfiles.d
/// entry applied there (systemd-tmpfiles --root), and the bridge and the
/// command mux started as their units say, as user `farsight`, on the
/// installed binaries and configs. They start, a laptop sees both, and
/// every installed file is readable by `farsight` while the zenoh secrets
/// are not readable by anybody else.
#[test]
fn the_installed_bridge_and_a_stage_run_as_the_farsight_user() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let (uid, gid) = farsight_user();
    let ns = Namespace::new("asuser");
    std::fs::set_permissions(&ns.root, std::fs::Permissions::from_mode(0o755)).unwrap();
    let (prefix, _) = stage(&ns, &[]);
    let etc = prefix.join("etc/farsight");
    let zenoh_dir = etc.join("zenoh");
    for f in ["robot.json5", "users.txt"] {
        let m = std::fs::metadata(zenoh_dir.join(f)).unwrap();
        assert_eq!(
            (m.uid(), m.gid(), m.mode() & 0o777),
            (0, gid, 0o640),
            "{f}: root:farsight 0640"
        );
    }
    let m = std::fs::metadata(&zenoh_dir).unwrap();
    assert_eq!(
        (m.gid(), m.mode() & 0o777),
        (gid, 0o750),
        "etc/farsight/zenoh"
    );

    // The tmpfiles.d entry, applied by systemd-tmpfiles under the prefix
    // (it resolves the user in the prefix's /etc/passwd).
    let getent = |db: &str| {
        let out = Command::new("getent")
            .args([db, "farsight"])
            .output()
            .unwrap();
        String::from_utf8(out.stdout).unwrap()
    };
    std::fs::write(prefix.join("etc/passwd"), getent("passwd")).unwrap();
    std::fs::write(prefix.join("etc/group"), getent("group")).unwrap();
    let out = Command::new("systemd-tmpfiles")
        .arg("--create")
        .arg(format!("--root={}", prefix.display()))
        .arg(prefix.join("usr/lib/tmpfiles.d/farsight.conf"))
        .output()
        .unwrap();
    assert!(out.status.success(), "systemd-tmpfiles: {out:?}");
    let ipc = std::fs::metadata(prefix.join("run/farsight/iceoryx2")).unwrap();
    assert_eq!((ipc.uid(), ipc.gid()), (uid, gid));
    // iceoryx2's socket paths must stay under 108 bytes, as they do under
    // /run/farsight: the units get the prefix's run/farsight by a short link.
    struct Link(PathBuf);
    impl Drop for Link {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }
    let run = Link(PathBuf::from(format!("/tmp/fsrun-{}", ns.prefix)));
    std::os::unix::fs::symlink(prefix.join("run/farsight"), &run.0).unwrap();

    // The router listens on a free port with the installed users file (the
    // installed paths are under the prefix); written in place, so the
    // file keeps its owner and mode.
    let router = zenoh_dir.join("robot.json5");
    let text = std::fs::read_to_string(&router).unwrap();
    let port = free_port();
    std::fs::write(
        &router,
        text.replace("tcp/0.0.0.0:7447", &format!("tcp/127.0.0.1:{port}"))
            .replace(
                "/etc/farsight/zenoh/users.txt",
                zenoh_dir.join("users.txt").to_str().unwrap(),
            ),
    )
    .unwrap();

    // Nothing installed is unreadable to farsight...
    let unreadable = |reuid: &str, regid: &str, groups: &str, dirs: &[PathBuf]| {
        let out = Command::new("setpriv")
            .args([reuid, regid, groups, "--", "find"])
            .args(dirs)
            .args(["!", "-readable"])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr)
    };
    let installed = [etc.clone(), prefix.join("usr/local")];
    let found = unreadable(
        "--reuid=farsight",
        "--regid=farsight",
        "--init-groups",
        &installed,
    );
    assert!(found.trim().is_empty(), "unreadable as farsight:\n{found}");
    // ...and the secrets are unreadable to anybody else.
    let found = unreadable(
        "--reuid=65534",
        "--regid=65534",
        "--clear-groups",
        &installed,
    );
    for f in ["zenoh/robot.json5", "zenoh/users.txt"] {
        assert!(
            found.contains(etc.join(f).to_str().unwrap())
                || found.contains(zenoh_dir.to_str().unwrap()),
            "{f} readable by nobody:\n{found}"
        );
    }

    let start = |unit: &str, stage: &str| {
        let p = Proc::spawn(unit, as_unit(&ns, &prefix, &run.0, unit));
        let ready = format!("{stage} ready");
        p.wait_line(Duration::from_secs(30), |l| l == ready)
            .unwrap_or_else(|| panic!("{unit} as farsight did not start:\n{}", p.stderr_so_far()));
        p
    };
    let mut mux = start("farsight-command-mux.service", "command-mux");
    let mut bridge = start("farsight-bridge.service", "bridge");
    let owner = |p: &Proc| {
        std::fs::metadata(format!("/proc/{}", p.pid()))
            .map(|m| (m.uid(), m.gid()))
            .unwrap()
    };
    assert_eq!(owner(&mux), (uid, gid));
    assert_eq!(owner(&bridge), (uid, gid));

    // A laptop sees the bridge alive and the mux's health, which crossed
    // iceoryx2 from one farsight process to the other and zenoh to here.
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let laptop = login(&endpoint, "laptop", "laptop-secret");
    assert_eq!(alive(&laptop), ["farsight/robot/alive/bridge"]);
    let (code, view) = Proc::farsight_as(
        None,
        &ns,
        "laptop",
        "laptop-secret",
        &[
            "inspect",
            "--connect",
            &endpoint,
            "--robot",
            "robot",
            "--seconds",
            "2.5",
        ],
    );
    assert_eq!(code, Some(0), "{view}");
    assert!(
        view.lines()
            .any(|l| l.trim_start().starts_with("command-mux")),
        "{view}"
    );
    let logs = format!("{}\n{}", mux.stderr_so_far(), bridge.stderr_so_far());
    assert!(!logs.contains("Permission denied"), "{logs}");
    assert!(!logs.contains("access_control"), "{logs}");
    assert_eq!(bridge.terminate(Duration::from_secs(10)), Some(0));
    assert_eq!(mux.terminate(Duration::from_secs(10)), Some(0));

    // The check can fail: with the router config root:root, as the
    // installer left it before, the bridge cannot read it.
    std::os::unix::fs::chown(&router, Some(0), Some(0)).unwrap();
    let mut denied = Proc::spawn(
        "farsight-bridge.service",
        as_unit(&ns, &prefix, &run.0, "farsight-bridge.service"),
    );
    assert_eq!(denied.wait_exit(Duration::from_secs(10)), Some(1));
    let err = denied.stderr_to_end();
    assert!(err.contains("Permission denied"), "{err}");
}
