//! `sdictl snapshot --by-path` and `record --by-path` into the service's
//! state directory as it is installed (root:sdi, 0750 by the unit's
//! StateDirectoryMode, or 0770): a member of the group who does not own
//! the directory is served, whatever the group bits (the daemon creates the
//! file itself; no writability check of the caller's). Root sdid, caller
//! uid 65534 in group 4242 through `setpriv`; skipped unless root.

use std::fs;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::process::{Command, Stdio};
use std::time::Duration;

use sdi_tests::dbus::{bin, Bus, Daemon};
use sdi_tests::process::runnable_copy;
use sdi_tests::require_dbus;
use sdi_tests::wait::wait_until;

const CALLER_UID: u32 = 65534;
const GROUP_GID: u32 = 4242;

#[test]
fn group_members_write_by_path_into_a_root_group_state_dir() {
    require_dbus!();
    if !sdi_tests::process::is_root() || Command::new("setpriv").arg("--version").output().is_err()
    {
        sdi_tests::skipped!("SKIPPED: needs root and setpriv (util-linux)");
        return;
    }
    for mode in [0o750, 0o770] {
        let dir = tempfile::Builder::new()
            .prefix("sdi-group-")
            .tempdir_in("/var/tmp")
            .unwrap();
        let root = dir.path();
        fs::set_permissions(root, fs::Permissions::from_mode(0o755)).unwrap();
        let state = root.join("state");
        fs::create_dir(&state).unwrap();
        std::os::unix::fs::chown(&state, Some(0), Some(GROUP_GID)).unwrap();
        fs::set_permissions(&state, fs::Permissions::from_mode(mode)).unwrap();
        let bus = Bus::start_open(root);
        let _sdid = Daemon::spawn(
            &bus,
            Daemon::bare_command(&bus, &[])
                .args(["--backend", "sim"])
                .args(["--sink", "y4m", "--y4m-path", "-", "--frame-rate-hz", "30"])
                .args(["--state-dir", state.to_str().unwrap()])
                .stdout(Stdio::null()),
        );
        let sdictl = runnable_copy(&bin("sdictl"), &root.join("bin"));
        let as_member = |args: &[&str]| {
            let uid = CALLER_UID.to_string();
            Command::new("setpriv")
                .args(["--reuid", &uid, "--regid", &uid])
                .args(["--groups", &GROUP_GID.to_string()])
                .arg(&sdictl)
                .args(["--bus-address", &bus.address])
                .args(args)
                .output()
                .expect("run setpriv sdictl")
        };
        wait_until("sdid to answer the member", Duration::from_secs(30), || {
            as_member(&["get", "mode"]).status.success()
        });
        let png = state.join("member.png");
        let out = as_member(&["snapshot", "--by-path", png.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{mode:o}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(fs::metadata(&png).unwrap().uid(), CALLER_UID, "{mode:o}");
        let rec = state.join("member.sdirec");
        let out = as_member(&[
            "record",
            "--by-path",
            rec.to_str().unwrap(),
            "--seconds",
            "0.3",
        ]);
        assert!(
            out.status.success(),
            "{mode:o}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(fs::metadata(&rec).unwrap().len() > 0, "{mode:o}");
    }
}
