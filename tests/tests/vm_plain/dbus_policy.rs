//! SDI's D-Bus system policy (`udev/dbus/org.sdi.Daemon.conf`) on a real
//! dbus-daemon configured like the system bus.
//!
//! Runs inside the VM, whose `/etc` is a throw-away overlay, so the test can
//! create the control group `sdi`, a member of it and an unprivileged user
//! without touching the host. The daemon owning `org.sdi.Daemon` runs as
//! root; the users talk to it with `busctl` through `runuser`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use sdi_tests::dbus::{bin, Bus};
use sdi_tests::process::{must, repo_root, run, Reaped};
use sdi_tests::sdid_command::SdidCommand;

const BUS_NAME: &str = "org.sdi.Daemon";
const OBJECT: &str = "/org/sdi/Camera0";
const INTERFACE: &str = "org.sdi.Camera1";
const OPERATOR: &str = "sdi-operator";
const GUEST: &str = "sdi-guest";

/// A private bus with the system bus's deny-by-default policy plus SDI's.
struct SystemLikeBus {
    _daemon: Bus,
    address: String,
}

impl SystemLikeBus {
    fn start(dir: &Path) -> Self {
        let socket = dir.join("system_bus_socket");
        let services = dir.join("system-services");
        std::fs::create_dir_all(&services).unwrap();
        let template =
            std::fs::read_to_string(repo_root().join("tests/system/dbus-system-bus.conf.in"))
                .unwrap();
        let config = template
            .replace("@SOCKET@", socket.to_str().unwrap())
            .replace("@SERVICEDIR@", services.to_str().unwrap())
            .replace(
                "@POLICY@",
                repo_root()
                    .join("udev/dbus/org.sdi.Daemon.conf")
                    .to_str()
                    .unwrap(),
            );
        let config_path = dir.join("system.conf");
        std::fs::write(&config_path, config).unwrap();
        let bus = Bus::start_config(&config_path);
        Self {
            address: bus.address.clone(),
            _daemon: bus,
        }
    }

    /// `busctl` on this bus as `user` (None: as root).
    fn busctl(&self, user: Option<&str>, args: &[&str]) -> Output {
        let mut cmd = match user {
            Some(u) => {
                let mut c = Command::new("runuser");
                c.args(["-u", u, "--", "busctl"]);
                c
            }
            None => Command::new("busctl"),
        };
        cmd.arg(format!("--address={}", self.address))
            .arg("--timeout=5")
            .args(args);
        run(&mut cmd)
    }

    fn wait_for_owner(&self, name: &str) {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let out = self.busctl(
                None,
                &[
                    "call",
                    "org.freedesktop.DBus",
                    "/org/freedesktop/DBus",
                    "org.freedesktop.DBus",
                    "NameHasOwner",
                    "s",
                    name,
                ],
            );
            if String::from_utf8_lossy(&out.stdout).trim() == "b true" {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "{name} never appeared on the bus"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

fn denied(out: &Output) -> bool {
    let err = String::from_utf8_lossy(&out.stderr);
    !out.status.success() && (err.contains("Access denied") || err.contains("AccessDenied"))
}

/// The real sdid owning `org.sdi.Daemon` as root, on the simulator, connected
/// the production way (system bus; here the address of the test bus).
fn start_daemon(bus: &SystemLikeBus) -> Reaped {
    let child = SdidCommand::new()
        .sim()
        .args(["--sink", "y4m"])
        .command()
        .env("DBUS_SYSTEM_BUS_ADDRESS", &bus.address)
        .stdout(Stdio::null())
        .spawn()
        .expect("spawn sdid");
    Reaped(child)
}

#[test]
fn policy_controls_who_may_do_what() {
    if crate::GUEST.on_host() {
        return;
    }
    must(Command::new("groupadd").args(["--system", "sdi"]));
    must(Command::new("useradd").args(["-M", "-N", "-G", "sdi", OPERATOR]));
    must(Command::new("useradd").args(["-M", "-N", GUEST]));

    let dir = PathBuf::from("/tmp/sdi-dbus-policy");
    std::fs::create_dir_all(&dir).unwrap();
    let bus = SystemLikeBus::start(&dir);
    let _daemon = start_daemon(&bus);
    bus.wait_for_owner(BUS_NAME);

    // Control: only members of the group may call methods.
    let call = [
        "call",
        BUS_NAME,
        OBJECT,
        INTERFACE,
        "SetMode",
        "s",
        "depth-edge",
    ];
    let guest = bus.busctl(Some(GUEST), &call);
    assert!(denied(&guest), "an unprivileged user could call SetMode");
    let operator = bus.busctl(Some(OPERATOR), &call);
    assert!(
        operator.status.success(),
        "a member of sdi could not call SetMode"
    );

    // Reading: everyone, including reading back the mode just set.
    for user in [GUEST, OPERATOR] {
        let get = bus.busctl(
            Some(user),
            &["get-property", BUS_NAME, OBJECT, INTERFACE, "Mode"],
        );
        assert!(get.status.success(), "{user} could not read Mode");
        assert!(String::from_utf8_lossy(&get.stdout).contains("depth-edge"));
        let all = bus.busctl(
            Some(user),
            &[
                "call",
                BUS_NAME,
                OBJECT,
                "org.freedesktop.DBus.Properties",
                "GetAll",
                "s",
                INTERFACE,
            ],
        );
        assert!(all.status.success(), "{user} could not GetAll");
        let intro = bus.busctl(Some(user), &["introspect", BUS_NAME, OBJECT]);
        assert!(intro.status.success(), "{user} could not introspect");
        let ping = bus.busctl(
            Some(user),
            &[
                "call",
                BUS_NAME,
                OBJECT,
                "org.freedesktop.DBus.Peer",
                "Ping",
            ],
        );
        assert!(ping.status.success(), "{user} could not ping");
    }

    // Setting properties: the policy lets only the group through (what the
    // daemon then does with the value is its business, not the bus's).
    let set = [
        "set-property",
        BUS_NAME,
        OBJECT,
        INTERFACE,
        "Mode",
        "s",
        "raw",
    ];
    assert!(
        denied(&bus.busctl(Some(GUEST), &set)),
        "guest could set a property"
    );
    assert!(
        !denied(&bus.busctl(Some(OPERATOR), &set)),
        "the bus denied a member of sdi setting a property"
    );

    // Output files by descriptor: sdictl, run as the user, creates the file
    // in a directory only that user may write and passes it to the daemon.
    let sdictl = sdi_tests::process::runnable_copy(&bin("sdictl"), &dir);
    let snapshot_as = |user: &str, file: &Path| {
        run(Command::new("runuser")
            .args(["-u", user, "--", "env"])
            .arg(format!("DBUS_SYSTEM_BUS_ADDRESS={}", bus.address))
            .arg(&sdictl)
            .arg("snapshot")
            .arg(file))
    };
    let own_dir = |user: &str| {
        let d = dir.join(format!("out-{user}"));
        std::fs::create_dir_all(&d).unwrap();
        must(Command::new("chown").arg(user).arg(&d));
        must(Command::new("chmod").arg("0700").arg(&d));
        d
    };
    let op_dir = own_dir(OPERATOR);
    let snap = op_dir.join("snap.npy");
    assert!(
        snapshot_as(OPERATOR, &snap).status.success(),
        "a member of sdi could not snapshot through a descriptor"
    );
    let meta = std::fs::metadata(&snap).unwrap();
    assert!(meta.len() > 128, "empty snapshot");
    let op_uid = String::from_utf8_lossy(&must(Command::new("id").args(["-u", OPERATOR])).stdout)
        .trim()
        .parse::<u32>()
        .unwrap();
    assert_eq!(std::os::unix::fs::MetadataExt::uid(&meta), op_uid);
    let guest_dir = own_dir(GUEST);
    let denied_snapshot = snapshot_as(GUEST, &guest_dir.join("snap.npy"));
    assert!(
        !denied_snapshot.status.success()
            && String::from_utf8_lossy(&denied_snapshot.stderr).contains("AccessDenied"),
        "an unprivileged user could snapshot"
    );
    let left: Vec<_> = std::fs::read_dir(&guest_dir).unwrap().collect();
    assert!(left.is_empty(), "a denied snapshot left {left:?}");

    // Ownership: nobody but root may take the name.
    for user in [GUEST, OPERATOR] {
        let own = run(Command::new("runuser")
            .args(["-u", user, "--", "dbus-send"])
            .args([
                &format!("--bus={}", bus.address),
                "--print-reply",
                "--dest=org.freedesktop.DBus",
                "/org/freedesktop/DBus",
                "org.freedesktop.DBus.RequestName",
                &format!("string:{BUS_NAME}"),
                "uint32:0",
            ]));
        assert!(denied(&own), "{user} could own {BUS_NAME}");
    }
}
