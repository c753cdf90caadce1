//! Graph files (`graphs/*.toml`) through the real `farsight graph check`:
//! every shipped graph checks, a broken one fails naming node and topic for
//! each problem, the drawing names every node, and the robot's systemd
//! target starts exactly the robot graph's nodes.

use farsight_tests::{bin, repo_root, Namespace};
use std::process::Command;

fn check(graph: &std::path::Path, extra: &[&str]) -> (bool, String) {
    let out = Command::new(bin("farsight"))
        .args(["graph", "check"])
        .arg(graph)
        .args(extra)
        .output()
        .expect("farsight graph check");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

fn shipped_graphs() -> Vec<std::path::PathBuf> {
    let mut graphs: Vec<_> = std::fs::read_dir(repo_root().join("graphs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    graphs.sort();
    graphs
}

#[test]
fn every_shipped_graph_checks_and_draws() {
    let ns = Namespace::new("graphcheck");
    let graphs = shipped_graphs();
    assert!(graphs.len() >= 3, "{graphs:?}");
    for g in graphs {
        let mmd = ns.root.join("g.mmd");
        let dot = ns.root.join("g.dot");
        let (ok, text) = check(
            &g,
            &[
                "--mermaid",
                mmd.to_str().unwrap(),
                "--dot",
                dot.to_str().unwrap(),
            ],
        );
        assert!(ok, "{}:\n{text}", g.display());
        assert!(text.trim_end().ends_with("ok"), "{text}");
        let graph: toml::Table = toml::from_str(&std::fs::read_to_string(&g).unwrap()).unwrap();
        let (mermaid, dot) = (
            std::fs::read_to_string(&mmd).unwrap(),
            std::fs::read_to_string(&dot).unwrap(),
        );
        assert!(mermaid.starts_with("flowchart LR") && dot.starts_with("digraph"));
        for node in graph["node"].as_array().unwrap() {
            let name = node["name"].as_str().unwrap();
            assert!(text.contains(name), "{name} not in the table:\n{text}");
            assert!(
                mermaid.contains(name) && dot.contains(name),
                "{name} not drawn"
            );
        }
    }
}

#[test]
fn four_cameras_share_one_inference_process_each_with_its_own_health() {
    let (ok, text) = check(&repo_root().join("graphs/four-cameras.toml"), &[]);
    assert!(ok, "{text}");
    let writer = |topic: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("{topic} ")))
            .and_then(|l| l.split_whitespace().nth(2))
            .map(str::to_string)
    };
    for cam in ["front", "left", "rear", "right"] {
        assert_eq!(
            writer(&format!("health/inference-{cam}")).as_deref(),
            Some("inference"),
            "{cam}:\n{text}"
        );
        assert_eq!(
            writer(&format!("perception/{cam}/heatmap")).as_deref(),
            Some("inference"),
            "{cam}:\n{text}"
        );
        assert!(
            text.lines()
                .any(|l| l.starts_with(&format!("perception/{cam}/heatmap "))
                    && l.contains("bin-projection (R)")),
            "{cam}:\n{text}"
        );
    }
}

#[test]
fn a_broken_graph_fails_naming_node_and_topic() {
    let ns = Namespace::new("graphbroken");
    let graph = ns.write(
        "broken.toml",
        r#"
[[node]]
name = "servo"
stage = "velocity-servoing"
[node.config]
track = "path"
path_topic = "planned"

[[node]]
name = "servo-two"
stage = "velocity-servoing"

[[node]]
name = "ghost"
stage = "teleporter"

[[node]]
name = "bins"
stage = "bin-projection"
[node.config]
method = "lrn"
bin_widht_deg = 5.0

[[node]]
name = "guided"
stage = "subgoal-selection"
[node.config]
guide = "nav/goal"

[[node]]
name = "inference"
stage = "inference"
[node.config]
backend = "hsv"
camera = "front"
[[node.config.hsv.ranges]]
hue_deg = [20.0, 50.0]
saturation = [0.0, 0.35]
value = [0.35, 1.0]
"#,
    );
    let (ok, text) = check(&graph, &[]);
    assert!(!ok, "{text}");
    for expected in [
        // An input nothing writes.
        "node `servo` reads `nav/path/planned`, which nothing writes",
        "node `inference` reads `camera/front/image`, which nothing writes",
        // Two writers.
        "topic `cmd/velocity`: two writers (servo, servo-two)",
        // An unknown stage kind.
        "node `ghost`: unknown stage kind `teleporter`",
        // An unknown config key, named by the stage's own config check.
        "node `bins` (bin-projection):",
        "unknown field `bin_widht_deg`",
        // A type mismatch: a topic's kind is its name's, so a config that
        // points a Subgoal input at the goal (a NavGoal) is refused there.
        "node `guided` (subgoal-selection): config key `guide` = nav/goal: expected a nav/subgoal/<name> topic",
    ] {
        assert!(text.contains(expected), "missing {expected:?}:\n{text}");
    }
}

#[test]
fn more_subscribers_than_the_transport_allows_is_refused() {
    let ns = Namespace::new("graphfanout");
    let mut graph = String::from("[[external]]\ntopic = \"nav/subgoal\"\nfrom = \"a test\"\n");
    for k in 0..13 {
        graph.push_str(&format!(
            "[[node]]\nname = \"servo-{k}\"\nstage = \"velocity-servoing\"\n[node.config]\ncommand_topic = \"cmd/s{k}\"\n"
        ));
    }
    let (ok, text) = check(&ns.write("fanout.toml", &graph), &[]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("topic `nav/subgoal` on robot: 13 subscribers, the transport allows 12"),
        "{text}"
    );
}

#[test]
fn the_robots_systemd_target_starts_exactly_the_robot_graphs_nodes() {
    let graph: toml::Table =
        toml::from_str(&std::fs::read_to_string(repo_root().join("graphs/robot.toml")).unwrap())
            .unwrap();
    let mut nodes: Vec<String> = graph["node"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            // On the robot each node is its stage's unit and config file.
            let (name, stage) = (n["name"].as_str().unwrap(), n["stage"].as_str().unwrap());
            assert_eq!(name, stage, "one instance per stage kind on the robot");
            assert_eq!(
                n["config"].as_str().unwrap(),
                format!("../deploy/config/{stage}.toml"),
                "the robot runs its installed configs"
            );
            format!("farsight-{stage}.service")
        })
        .collect();
    nodes.sort();
    let target =
        std::fs::read_to_string(repo_root().join("deploy/systemd/farsight.target")).unwrap();
    let mut wants: Vec<String> = target
        .lines()
        .find_map(|l| l.strip_prefix("Wants="))
        .unwrap()
        .split_whitespace()
        .map(String::from)
        .collect();
    wants.sort();
    assert_eq!(wants, nodes);
}

#[test]
fn an_instance_name_keys_the_health_topic_and_ready_line() {
    use farsight_interfaces::topics;
    use std::time::Duration;
    let ns = Namespace::new("instances");
    let bus = ns.bus("instance-test");
    let a = bus.subscriber(&topics::health("mux-a")).unwrap();
    let b = bus.subscriber(&topics::health("mux-b")).unwrap();
    let plain = bus.subscriber(&topics::health("command-mux")).unwrap();
    let mut procs = Vec::new();
    for (name, input) in [("mux-a", "cmd/a"), ("mux-b", "cmd/b")] {
        // Two instances of one stage kind on one bus (both publish
        // cmd/velocity, which iceoryx2 allows; `graph check` would not).
        let cfg = ns.write(
            &format!("{name}.toml"),
            &format!(
                "[[inputs]]\nname = \"x\"\ntopic = \"{input}\"\npriority = 1\nmax_ttl_s = 0.5\n"
            ),
        );
        let p = farsight_tests::Proc::start(
            "farsight-command-mux",
            &["--config", cfg.to_str().unwrap(), "--instance", name],
            &ns,
        );
        let ready = format!("{name} ready");
        p.wait_line(Duration::from_secs(30), |l| l == ready)
            .unwrap_or_else(|| panic!("{name}: {}", p.stderr_so_far()));
        procs.push(p);
    }
    for (sub, name) in [(&a, "mux-a"), (&b, "mux-b")] {
        let h = farsight_tests::wait_health(sub, Duration::from_secs(20), name, |_| true);
        assert_eq!(h.stage.as_str(), name);
    }
    assert!(
        plain.latest().unwrap().is_none(),
        "no report under the stage's own name"
    );
    let bad = std::process::Command::new(bin("farsight-command-mux"))
        .args(["--instance", "no spaces"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--instance \"no spaces\""));
}

#[test]
fn a_recorder_nodes_topics_are_queued_edges_and_a_second_queue_reader_is_refused() {
    let ns = Namespace::new("graphqueue");
    let recorder = |name: &str| {
        format!(
            "[[node]]\nname = \"{name}\"\nstage = \"recorder\"\n[node.config]\ntopics = [\"state/pose\", \"cmd/velocity\"]\nqueue_depth = 32\n\n"
        )
    };
    let base = "[[node]]\nname = \"servo\"\nstage = \"velocity-servoing\"\n\n[[external]]\ntopic = \"nav/subgoal\"\nfrom = \"the test\"\n\n[[external]]\ntopic = \"state/pose\"\nfrom = \"the test\"\n\n";
    let one = ns.write("one.toml", &format!("{base}{}", recorder("rec")));
    let (ok, text) = check(&one, &[]);
    assert!(ok, "{text}");
    assert!(
        text.contains("queue `state/pose`: depth 32 for rec"),
        "{text}"
    );
    let two = ns.write(
        "two.toml",
        &format!("{base}{}{}", recorder("rec"), recorder("rec-b")),
    );
    let (ok, text) = check(&two, &[]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("topic `cmd/velocity` on robot: 2 queue readers (rec, rec-b)"),
        "{text}"
    );
}
