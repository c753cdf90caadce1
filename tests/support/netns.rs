//! Two hosts on one machine for the tests: a "robot" and a "laptop" network
//! namespace joined by a veth pair (Debian's iproute2, run as root). Shared
//! memory is not namespaced, so the test process still sees the robot's
//! iceoryx2 graph; only zenoh crosses the link.

use std::process::Command;

fn ip(args: &[&str]) {
    let out = Command::new("ip")
        .args(args)
        .output()
        .expect("iproute2's ip");
    assert!(
        out.status.success(),
        "ip {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The two namespaces and the link; removed on drop.
pub struct TwoHosts {
    pub robot: String,
    pub laptop: String,
    /// The robot's address on the link.
    pub robot_ip: String,
    robot_if: String,
}

impl TwoHosts {
    /// `tag` keeps parallel tests apart (a few letters or digits).
    pub fn new(tag: &str) -> Self {
        let id = std::process::id() % 10_000;
        let (robot, laptop) = (format!("fsr{tag}{id}"), format!("fsl{tag}{id}"));
        let (rif, lif) = (format!("vr{tag}{id}"), format!("vl{tag}{id}"));
        let net = 10 + (id % 200);
        let sub = tag.bytes().map(u32::from).sum::<u32>() % 250;
        let robot_ip = format!("10.{net}.{sub}.1");
        ip(&["netns", "add", &robot]);
        ip(&["netns", "add", &laptop]);
        ip(&["link", "add", &rif, "type", "veth", "peer", "name", &lif]);
        ip(&["link", "set", &rif, "netns", &robot]);
        ip(&["link", "set", &lif, "netns", &laptop]);
        for (ns, dev, addr) in [
            (&robot, &rif, format!("{robot_ip}/24")),
            (&laptop, &lif, format!("10.{net}.{sub}.2/24")),
        ] {
            ip(&["-n", ns, "addr", "add", &addr, "dev", dev]);
            ip(&["-n", ns, "link", "set", dev, "up"]);
            ip(&["-n", ns, "link", "set", "lo", "up"]);
        }
        Self {
            robot,
            laptop,
            robot_ip,
            robot_if: rif,
        }
    }

    /// Takes the link down or up (from the robot's side).
    pub fn link(&self, up: bool) {
        ip(&[
            "-n",
            &self.robot,
            "link",
            "set",
            &self.robot_if,
            if up { "up" } else { "down" },
        ]);
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        for ns in [&self.robot, &self.laptop] {
            let _ = Command::new("ip").args(["netns", "del", ns]).status();
        }
    }
}
