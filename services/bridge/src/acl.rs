//! The robot's zenoh router config (`deploy/zenoh/robot.json5`), whose
//! access control comes from one function, [`access_control`], over the
//! bridge's robot name and import list:
//!
//! - `laptop` may subscribe to, query and list (liveliness) everything
//!   under `farsight/<robot>/**`, and write nothing: no put, no delete, no
//!   liveliness token, no queryable, no reply;
//! - `operator` has the laptop's rights plus `put` on exactly the imported
//!   keys (`farsight/<robot>/<import>`);
//! - everything else is denied (`default_permission: "deny"`).
//!
//! `farsight-bridge --config bridge.toml --print-router-config` prints the
//! whole router config; `deploy/install.sh` writes it from the installed
//! `bridge.toml`, and a test keeps `deploy/zenoh/robot.json5` equal to what
//! `deploy/config/bridge.toml` generates. The bridge warns at start-up when
//! the ACL it loaded is not the one its import list implies.

use crate::{BridgeConfig, ImportConfig};
use farsight_interfaces::topics;

/// The read-only user of a laptop (deploy/zenoh/users.txt).
pub const LAPTOP: &str = "laptop";
/// The user that may also command the robot: put on the imported keys.
pub const OPERATOR: &str = "operator";
/// Where the robot's router listens.
pub const ROUTER_LISTEN: &str = "tcp/0.0.0.0:7447";
/// The router's user/password dictionary, as installed.
pub const USERS_FILE: &str = "/etc/farsight/zenoh/users.txt";

/// Messages a remote sends to the router (`ingress`) or receives from it (`egress`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Ingress,
    Egress,
}

impl Flow {
    pub fn name(self) -> &'static str {
        match self {
            Flow::Ingress => "ingress",
            Flow::Egress => "egress",
        }
    }
}

/// zenoh 1.x ACL message kinds (zenoh-config's `AclMessage`) that write:
/// none of them may come in from a laptop, only `put` from an operator.
pub const WRITES: [&str; 5] = [
    "put",
    "delete",
    "liveliness_token",
    "declare_queryable",
    "reply",
];

/// One allow rule of the ACL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rule {
    pub id: &'static str,
    pub flow: Flow,
    pub messages: Vec<&'static str>,
    pub key_exprs: Vec<String>,
}

/// Rules granted to subjects (usernames).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Policy {
    pub rules: Vec<&'static str>,
    pub users: Vec<&'static str>,
}

/// The router's `access_control` section.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AccessControl {
    pub rules: Vec<Rule>,
    pub policies: Vec<Policy>,
}

/// The ACL of robot `robot` whose bridge imports `imports`.
pub fn access_control(robot: &str, imports: &[ImportConfig]) -> AccessControl {
    let all = format!("farsight/{robot}/**");
    let mut rules = vec![
        Rule {
            id: "read the graph",
            flow: Flow::Ingress,
            messages: vec![
                "declare_subscriber",
                "declare_liveliness_subscriber",
                "liveliness_query",
                "query",
            ],
            key_exprs: vec![all.clone()],
        },
        // What the router sends back: data, replies, the live stages'
        // tokens, and which keys have subscribers (a client's publisher
        // sends nothing to a key nobody subscribes to).
        Rule {
            id: "receive the graph",
            flow: Flow::Egress,
            messages: vec!["put", "reply", "liveliness_token", "declare_subscriber"],
            key_exprs: vec![all],
        },
    ];
    let mut policies = vec![Policy {
        rules: vec!["read the graph", "receive the graph"],
        users: vec![LAPTOP, OPERATOR],
    }];
    let mut commands: Vec<String> = Vec::new();
    for key in imports.iter().map(|i| topics::zenoh_key(robot, &i.topic)) {
        if !commands.contains(&key) {
            commands.push(key);
        }
    }
    // zenoh refuses a rule without key expressions: no imports, no rule.
    if !commands.is_empty() {
        rules.push(Rule {
            id: "command the robot",
            flow: Flow::Ingress,
            messages: vec!["put"],
            key_exprs: commands,
        });
        policies.push(Policy {
            rules: vec!["command the robot"],
            users: vec![OPERATOR],
        });
    }
    AccessControl { rules, policies }
}

fn quote(s: &str) -> String {
    serde_json::to_string(s).expect("a string serializes")
}

fn quoted(items: &[impl AsRef<str>]) -> String {
    let q: Vec<String> = items.iter().map(|s| quote(s.as_ref())).collect();
    format!("[{}]", q.join(", "))
}

fn subject_id(user: &str) -> String {
    format!("{user}s")
}

impl AccessControl {
    /// The rules that apply to `user`.
    pub fn rules_of<'a>(&'a self, user: &'a str) -> impl Iterator<Item = &'a Rule> {
        self.rules.iter().filter(move |r| {
            self.policies
                .iter()
                .any(|p| p.users.contains(&user) && p.rules.contains(&r.id))
        })
    }

    /// The key expressions on which `user` may send `message` to the router.
    pub fn may_send(&self, user: &str, message: &str) -> Vec<String> {
        self.rules_of(user)
            .filter(|r| r.flow == Flow::Ingress && r.messages.contains(&message))
            .flat_map(|r| r.key_exprs.iter().cloned())
            .collect()
    }

    /// The section as zenoh json5, each line indented by `indent`.
    pub fn to_json5(&self, indent: &str) -> String {
        let mut users: Vec<&str> = Vec::new();
        for p in &self.policies {
            for u in &p.users {
                if !users.contains(u) {
                    users.push(u);
                }
            }
        }
        let mut s = String::from("{\n");
        s += "  enabled: true,\n  default_permission: \"deny\",\n  rules: [\n";
        for r in &self.rules {
            s += &format!(
                "    {{\n      id: {},\n      permission: \"allow\",\n      flows: [\"{}\"],\n      messages: {},\n      key_exprs: {},\n    }},\n",
                quote(r.id),
                r.flow.name(),
                quoted(&r.messages),
                quoted(&r.key_exprs),
            );
        }
        s += "  ],\n  subjects: [\n";
        for u in &users {
            s += &format!(
                "    {{ id: {}, usernames: {} }},\n",
                quote(&subject_id(u)),
                quoted(&[u])
            );
        }
        s += "  ],\n  policies: [\n";
        for p in &self.policies {
            let subjects: Vec<String> = p.users.iter().map(|u| subject_id(u)).collect();
            s += &format!(
                "    {{ rules: {}, subjects: {} }},\n",
                quoted(&p.rules),
                quoted(&subjects)
            );
        }
        s += "  ],\n}";
        s.lines()
            .enumerate()
            .map(|(i, l)| {
                if i == 0 || l.is_empty() {
                    l.to_string()
                } else {
                    format!("{indent}{l}")
                }
            })
            .collect::<Vec<_>>()
            .join("\n")
    }
}

/// The robot's whole router config (what `deploy/zenoh/robot.json5` holds)
/// for the bridge config `cfg`.
pub fn router_config(cfg: &BridgeConfig) -> String {
    let acl = access_control(&cfg.robot, &cfg.import);
    let imported: Vec<&str> = cfg.import.iter().map(|i| i.topic.as_str()).collect();
    format!(
        r#"// The robot's zenoh router (the bridge loads it: bridge.toml [zenoh]
// config_file = "zenoh/robot.json5"). Laptops connect with a user and
// password from users.txt:
// - "{LAPTOP}": may subscribe to, query and list everything under
//   farsight/{robot}/**, and write nothing (no put, no delete, no
//   liveliness token, no queryable);
// - "{OPERATOR}": may also put on the bridge's imports:
//   {imports}.
// Anything else is denied.
//
// Generated from bridge.toml (its robot and [[import]] list) by
//   farsight-bridge --config /etc/farsight/bridge.toml --print-router-config
// (deploy/install.sh runs it). Change bridge.toml and regenerate rather
// than editing access_control by hand: the bridge warns when the two
// disagree. Change the passwords here and in users.txt for each robot.
{{
  mode: "router",
  listen: {{ endpoints: ["{ROUTER_LISTEN}"] }},
  scouting: {{ multicast: {{ enabled: false }} }},
  transport: {{
    auth: {{
      usrpwd: {{
        user: "robot",
        password: "robot-secret",
        dictionary_file: "{USERS_FILE}",
      }},
    }},
  }},
  access_control: {acl},
}}
"#,
        robot = cfg.robot,
        imports = if imported.is_empty() {
            "none".to_string()
        } else {
            imported.join(", ")
        },
        acl = acl.to_json5("  "),
    )
}

/// `None` when `loaded` (a zenoh config the bridge is about to open) has
/// access control off, or exactly the ACL [`access_control`] gives for
/// `cfg`; otherwise why not.
pub fn mismatch(loaded: &zenoh::Config, cfg: &BridgeConfig) -> Option<String> {
    let have = loaded.get_json("access_control").ok()?;
    let enabled = loaded
        .get_json("access_control/enabled")
        .is_ok_and(|v| v.trim() == "true");
    if !enabled {
        return None;
    }
    let mut want = zenoh::Config::default();
    let text = access_control(&cfg.robot, &cfg.import).to_json5("");
    if let Err(e) = want.insert_json5("access_control", &text) {
        return Some(format!("the generated ACL does not load: {e}"));
    }
    let want = want.get_json("access_control").ok()?;
    (have != want).then(|| {
        "its access_control is not the one generated from this bridge's robot and imports \
         (regenerate: farsight-bridge --config BRIDGE.toml --print-router-config)"
            .to_string()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn repo(path: &str) -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(path)
    }

    fn shipped() -> BridgeConfig {
        farsight_stage::parse_config(
            &std::fs::read_to_string(repo("deploy/config/bridge.toml")).unwrap(),
            "deploy/config/bridge.toml",
        )
        .unwrap()
    }

    #[test]
    fn the_committed_router_config_is_the_generated_one() {
        let committed = std::fs::read_to_string(repo("deploy/zenoh/robot.json5")).unwrap();
        let generated = router_config(&shipped());
        assert!(
            committed == generated,
            "deploy/zenoh/robot.json5 differs from what deploy/config/bridge.toml generates; \
             regenerate it:\n  cargo run --release -p farsight-bridge -- --config deploy/config/bridge.toml \
             --print-router-config > deploy/zenoh/robot.json5\n--- generated:\n{generated}"
        );
    }

    #[test]
    fn zenoh_loads_the_generated_config_and_the_check_sees_a_change() {
        let cfg = shipped();
        let text = router_config(&cfg);
        let loaded = zenoh::Config::from_json5(&text).expect("zenoh accepts the router config");
        assert_eq!(mismatch(&loaded, &cfg), None);
        // One import more in bridge.toml, the file not regenerated: noticed.
        let mut more = cfg.clone();
        more.import.push(ImportConfig {
            topic: "state/pose".into(),
        });
        assert!(mismatch(&loaded, &more).is_some());
        // No imports: no command rule, and zenoh still accepts it.
        let none = BridgeConfig {
            import: vec![],
            ..cfg
        };
        let text = router_config(&none);
        zenoh::Config::from_json5(&text).expect("zenoh accepts an ACL without commands");
        assert!(access_control(&none.robot, &none.import)
            .may_send(OPERATOR, "put")
            .is_empty());
    }

    #[test]
    fn a_laptop_writes_nothing_and_an_operator_puts_exactly_the_imports() {
        let cfg = shipped();
        let acl = access_control(&cfg.robot, &cfg.import);
        for m in WRITES {
            assert!(acl.may_send(LAPTOP, m).is_empty(), "laptop may send {m}");
        }
        let imports: Vec<String> = cfg
            .import
            .iter()
            .map(|i| format!("farsight/robot/{}", i.topic))
            .collect();
        assert_eq!(acl.may_send(OPERATOR, "put"), imports);
        for m in WRITES.iter().filter(|m| **m != "put") {
            assert!(
                acl.may_send(OPERATOR, m).is_empty(),
                "operator may send {m}"
            );
        }
        // Both read the whole robot, nothing else.
        for user in [LAPTOP, OPERATOR] {
            assert_eq!(
                acl.may_send(user, "declare_subscriber"),
                ["farsight/robot/**"]
            );
        }
        assert!(acl.may_send("someone", "declare_subscriber").is_empty());
    }
}
