//! Two test hosts on one machine: network namespaces `robot` (the robot PC) and `op` (an
//! operator's machine) joined by a veth pair, made with iproute2's `ip` (root only) and deleted
//! when dropped. `scl bench latency --remote` measures across it and the whole-graph network
//! tests drive the graph across it; with [`crate::relay::Relay`] in `op` it also carries added
//! delay.

use std::net::Ipv4Addr;
use std::process::Command;

/// Why the namespaces or their link could not be set up or changed.
#[derive(Debug, thiserror::Error)]
pub enum NetnsError {
    /// Namespaces need root.
    #[error("network namespaces need root; run as root, e.g. with sudo")]
    NotRoot,
    /// No `ip`.
    #[error("network namespaces need `ip` (iproute2), which cannot be run: {0}")]
    NoIp(#[source] std::io::Error),
    /// The tag would make a name longer than an interface name holds, or ambiguous.
    #[error("namespace tag {0:?}: 1 to 3 lowercase ASCII letters")]
    BadTag(String),
    /// An `ip` command failed.
    #[error("ip {args}: {stderr}")]
    Ip {
        /// Its arguments.
        args: String,
        /// What it said.
        stderr: String,
    },
}

/// One end of a [`VethPair`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// The robot PC: `10.213.S.1`.
    Robot,
    /// The operator's machine: `10.213.S.2`.
    Operator,
}

/// Namespaces `sclr-TAGID` (robot) and `sclo-TAGID` (operator, [`names`]) joined by a veth
/// pair on a `/30`: the robot's end holds `10.213.S.1`, the operator's `10.213.S.2`. Both namespaces, and
/// with them the pair, are deleted on drop. Addresses inside namespaces never meet, so only the
/// names are made unique (the tag and this process's id).
#[derive(Debug)]
pub struct VethPair {
    names: [String; 2],
    devs: [String; 2],
    made: Vec<String>,
    subnet: u8,
}

fn ip(args: &[&str]) -> Result<(), NetnsError> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(NetnsError::NoIp)?;
    if out.status.success() {
        Ok(())
    } else {
        Err(NetnsError::Ip {
            args: args.join(" "),
            stderr: String::from_utf8_lossy(&out.stderr).trim().to_owned(),
        })
    }
}

/// `TAG` then the last five digits of a process id: unique among the pairs live at once, short
/// enough for an interface name (15 bytes: `vr` + 3 + 5).
fn suffix(tag: &str, pid: u32) -> String {
    format!("{tag}{}", pid % 100_000)
}

fn tag_ok(tag: &str) -> bool {
    (1..=3).contains(&tag.len()) && tag.bytes().all(|b| b.is_ascii_lowercase())
}

/// The robot's and the operator's namespace of the [`VethPair`] with `tag` that process `pid`
/// makes.
pub fn names(tag: &str, pid: u32) -> [String; 2] {
    let n = suffix(tag, pid);
    [format!("sclr-{n}"), format!("sclo-{n}")]
}

/// Whether namespace `name` is one that process `pid` makes for a [`VethPair`], whatever its
/// tag: how a check finds what a process left behind.
pub fn made_by(name: &str, pid: u32) -> bool {
    let Some(rest) = name
        .strip_prefix("sclr-")
        .or_else(|| name.strip_prefix("sclo-"))
    else {
        return false;
    };
    let digits = rest.trim_start_matches(|c: char| c.is_ascii_lowercase());
    tag_ok(&rest[..rest.len() - digits.len()]) && digits == (pid % 100_000).to_string()
}

impl VethPair {
    /// Makes the two namespaces and their link, both interfaces and loopbacks up. `tag` (1 to
    /// 3 lowercase ASCII letters) tells apart the pairs one process makes.
    pub fn new(tag: &str) -> Result<Self, NetnsError> {
        if !tag_ok(tag) {
            return Err(NetnsError::BadTag(tag.to_owned()));
        }
        if !nix::unistd::geteuid().is_root() {
            return Err(NetnsError::NotRoot);
        }
        let pid = std::process::id();
        let n = suffix(tag, pid);
        let subnet = u8::try_from(1 + pid % 250).unwrap_or(1);
        let mut pair = Self {
            names: names(tag, pid),
            devs: [format!("vr{n}"), format!("vo{n}")],
            made: Vec::new(),
            subnet,
        };
        for name in pair.names.clone() {
            ip(&["netns", "add", &name])?;
            pair.made.push(name);
        }
        let [robot, op] = &pair.names;
        let [rdev, odev] = &pair.devs;
        ip(&["link", "add", rdev, "type", "veth", "peer", "name", odev])?;
        ip(&["link", "set", rdev, "netns", robot])?;
        ip(&["link", "set", odev, "netns", op])?;
        for side in [Side::Robot, Side::Operator] {
            let (ns, dev) = (pair.netns(side), pair.dev(side));
            let addr = format!("{}/30", pair.addr(side));
            ip(&["-n", ns, "addr", "add", &addr, "dev", dev])?;
            ip(&["-n", ns, "link", "set", "lo", "up"])?;
            ip(&["-n", ns, "link", "set", dev, "up"])?;
        }
        Ok(pair)
    }

    fn index(side: Side) -> usize {
        match side {
            Side::Robot => 0,
            Side::Operator => 1,
        }
    }

    /// The namespace of `side` (its name under `/var/run/netns`).
    pub fn netns(&self, side: Side) -> &str {
        &self.names[Self::index(side)]
    }

    fn dev(&self, side: Side) -> &str {
        &self.devs[Self::index(side)]
    }

    /// The address of `side`'s end of the pair.
    pub fn addr(&self, side: Side) -> Ipv4Addr {
        let host = match side {
            Side::Robot => 1,
            Side::Operator => 2,
        };
        Ipv4Addr::new(10, 213, self.subnet, host)
    }

    /// The command prefix that runs a program inside `side`'s namespace (`ip netns exec NS`).
    pub fn exec_prefix(&self, side: Side) -> Vec<String> {
        ["ip", "netns", "exec", self.netns(side)]
            .map(str::to_owned)
            .to_vec()
    }

    /// `program` to run inside `side`'s namespace.
    pub fn command(&self, side: Side, program: impl AsRef<std::ffi::OsStr>) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", self.netns(side)]).arg(program);
        c
    }

    /// Takes the operator's interface down (`up == false`: every packet either way is lost, as
    /// a pulled cable) or brings it back.
    pub fn set_operator_link(&self, up: bool) -> Result<(), NetnsError> {
        let state = if up { "up" } else { "down" };
        let side = Side::Operator;
        ip(&["-n", self.netns(side), "link", "set", self.dev(side), state])
    }
}

impl Drop for VethPair {
    fn drop(&mut self) {
        // Deleting a namespace deletes its end of the pair, and with it the other.
        for n in &self.made {
            let _ = Command::new("ip").args(["netns", "del", n]).output();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_or_odd_tag_is_refused_before_anything_is_made() {
        for tag in ["abcd", "a-b", "é", "", "a1", "B"] {
            assert!(
                matches!(VethPair::new(tag), Err(NetnsError::BadTag(t)) if t == tag),
                "{tag}"
            );
        }
    }

    #[test]
    fn the_names_a_process_makes_are_recognised_and_no_others() {
        let [robot, op] = names("b", 123_456);
        assert_eq!(
            (robot.as_str(), op.as_str()),
            ("sclr-b23456", "sclo-b23456")
        );
        assert!(made_by(&robot, 123_456) && made_by(&op, 23_456));
        for other in [
            "sclr-b2345",
            "sclr-b234567",
            "sclr-23456",
            "sclx-b23456",
            "sclo-abcd23456",
            "sclo-B23456",
        ] {
            assert!(!made_by(other, 123_456), "{other}");
        }
    }
}
