//! The caller's groups (`sdi`, `video`): in this process, or only in the
//! group database (log out and in again).

use std::time::Duration;

use super::{output, Check, Status, Sys};

/// Groups of this process, and of the user in the group database.
pub(super) struct Groups {
    user: String,
    uid: u32,
    process: Vec<String>,
    database: Vec<String>,
    existing: Vec<String>,
}

pub(super) fn groups(sys: &Sys) -> Groups {
    let uid = nix::unistd::getuid().as_raw();
    let user = nix::unistd::User::from_uid(nix::unistd::getuid())
        .ok()
        .flatten()
        .map_or_else(|| uid.to_string(), |u| u.name);
    let process: Vec<String> = nix::unistd::getgroups()
        .unwrap_or_default()
        .into_iter()
        .chain([nix::unistd::getegid()])
        .filter_map(|g| {
            nix::unistd::Group::from_gid(g)
                .ok()
                .flatten()
                .map(|g| g.name)
        })
        .collect();
    let database = output("id", &["-Gn", &user], Duration::from_secs(5))
        .map(|s| s.split_whitespace().map(str::to_owned).collect())
        .unwrap_or_default();
    let existing = sys
        .read("/etc/group")
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.split(':').next().map(str::to_owned))
        .collect();
    Groups {
        user,
        uid,
        process,
        database,
        existing,
    }
}

/// The groups verdict (pure, unit-tested).
pub(super) fn groups_verdict(g: &Groups) -> Vec<Check> {
    let mut out = Vec::new();
    for (group, why) in [
        ("sdi", "controls sdid over D-Bus (sdictl)"),
        (
            "video",
            "opens /dev/video* outside a desktop session (ssh, services)",
        ),
    ] {
        let id = if group == "sdi" {
            "group-sdi"
        } else {
            "group-video"
        };
        let c = if g.uid == 0 {
            Check::new(id, Status::Ok, format!("root: no group {group} needed"))
        } else if g.process.iter().any(|p| p == group) {
            Check::new(id, Status::Ok, format!("{} is in group {group}", g.user))
        } else if !g.existing.iter().any(|e| e == group) {
            Check::new(id, Status::Fail, format!("group {group} does not exist"))
                .fix(if group == "sdi" { "install sdid: sudo make install (systemd-sysusers creates group sdi from udev/sysusers.d)" } else { "sudo groupadd --system video" })
        } else if g.database.iter().any(|p| p == group) {
            Check::new(
                id,
                Status::Fail,
                format!(
                    "{} was added to group {group}, but this session started before",
                    g.user
                ),
            )
            .fix("log out and back in (or reboot); `newgrp` works for one shell")
        } else {
            Check::new(
                id,
                Status::Fail,
                format!("{} is not in group {group}, which {why}", g.user),
            )
            .fix(format!(
                "sudo usermod -aG {group} {}, then log out and back in",
                g.user
            ))
        };
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_tell_relogin_from_missing() {
        let g = |process: &[&str], database: &[&str]| Groups {
            user: "ann".into(),
            uid: 1000,
            process: process.iter().map(|s| (*s).to_owned()).collect(),
            database: database.iter().map(|s| (*s).to_owned()).collect(),
            existing: vec!["sdi".into(), "video".into()],
        };
        let v = groups_verdict(&g(&["sdi", "video"], &["sdi", "video"]));
        assert!(v.iter().all(|c| c.status == Status::Ok));
        let v = groups_verdict(&g(&["video"], &["sdi", "video"]));
        assert_eq!(v[0].status, Status::Fail);
        assert!(v[0].fix.as_deref().is_some_and(|f| f.contains("log out")));
        let v = groups_verdict(&g(&[], &[]));
        assert!(v[1]
            .fix
            .as_deref()
            .is_some_and(|f| f.contains("usermod -aG video ann")));
    }
}
