//! A private PipeWire session for tests and the sink benchmark: `pipewire`
//! and `wireplumber` under a temporary `XDG_RUNTIME_DIR`, on a private
//! session bus, plus `pw-dump` and `gst-launch-1.0 pipewiresrc` readers.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::dbus::Bus;
use crate::process::Reaped;
use crate::wait::wait_for;

/// Programs the PipeWire tests need, with the Debian package of each.
const TOOLS: [(&str, &[&str], &str); 6] = [
    ("dbus-daemon", &["--version"], "dbus"),
    ("pipewire", &["--version"], "pipewire"),
    ("wireplumber", &["--version"], "wireplumber"),
    ("pw-dump", &["--version"], "pipewire-bin"),
    ("gst-launch-1.0", &["--version"], "gstreamer1.0-tools"),
    ("gst-inspect-1.0", &["pipewiresrc"], "gstreamer1.0-pipewire"),
];

/// The PipeWire camera program, when it was built into this target
/// directory (`cargo build -p sdi-pipewire-camera`; the README's `cargo
/// test` leaves it out, as it needs libpipewire's headers).
pub fn camera_program() -> Option<PathBuf> {
    let p = crate::dbus::target_dir().join(sdi_daemon::sink::pipewire::CAMERA_PROGRAM);
    p.is_file().then_some(p)
}

/// Why the PipeWire tests cannot run here (a missing program), if so.
pub fn missing_tools() -> Option<String> {
    let mut missing: Vec<String> = TOOLS
        .iter()
        .filter(|(prog, args, _)| {
            !Command::new(prog)
                .args(*args)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        })
        .map(|(prog, _, pkg)| format!("{prog} ({pkg})"))
        .collect();
    if camera_program().is_none() {
        missing.push(format!(
            "{} (cargo build -p sdi-pipewire-camera, which needs {})",
            sdi_daemon::sink::pipewire::CAMERA_PROGRAM,
            sdi_daemon::sink::pipewire_launch::BUILD_PACKAGES
        ));
    }
    (!missing.is_empty()).then(|| format!("missing {}", missing.join(", ")))
}

/// Skips (with a message) when the PipeWire tools are missing, unless
/// `SDI_REQUIRE_VM` is set (CI), where that is a failure.
#[macro_export]
macro_rules! require_pipewire {
    () => {
        if let Some(why) = $crate::pipewire::missing_tools() {
            $crate::skip::unavailable(
                "SDI_REQUIRE_VM",
                format_args!("{why} (apt-get install pipewire pipewire-bin wireplumber gstreamer1.0-pipewire gstreamer1.0-tools)"),
            );
            return;
        }
    };
}

/// The node property WirePlumber (0.4 and 0.5) reads for how long a node
/// may idle before it suspends it (0: never); SDI's camera sets it to 0.
pub const SUSPEND_TIMEOUT_KEY: &str = "session.suspend-timeout-seconds";
/// WirePlumber's default for it.
pub const WIREPLUMBER_SUSPEND: Duration = Duration::from_secs(5);

/// `pipewire` + `wireplumber` on a private bus in a temporary runtime
/// directory; everything is killed on drop.
pub struct Session {
    // Dropped in order: the session manager before the daemon before the bus.
    _wireplumber: Reaped,
    _pipewire: Reaped,
    pub bus: Bus,
    pub dir: tempfile::TempDir,
    clients: Clients,
}

/// The session's clients (`pw-dump`, `pipewiresrc` readers, the camera).
impl std::ops::Deref for Session {
    type Target = Clients;
    fn deref(&self) -> &Clients {
        &self.clients
    }
}

/// How the test starts PipeWire clients of one session: with the private
/// session's environment ([`Session`]), or as a logged-in user in that
/// user's session, which their systemd manager runs ([`Clients::user`]).
#[derive(Debug, Clone)]
pub struct Clients {
    /// Runs the client as another user (`runuser -p -u NAME --`), or empty.
    prefix: Vec<String>,
    env: Vec<(String, String)>,
    /// Where the readers write (writable by the clients).
    scratch: PathBuf,
}

/// What a [`Session`] starts with beyond its defaults (a runtime directory
/// of its own, no user configuration).
#[derive(Default, Clone, Copy)]
pub struct SessionOptions<'a> {
    /// `XDG_RUNTIME_DIR`, fixed: a program started before the session (an
    /// sdid whose PipeWire camera waits for the daemon) finds its socket.
    pub runtime_dir: Option<&'a Path>,
    /// `XDG_CONFIG_HOME`: WirePlumber's user configuration (SDI's rule).
    pub config_home: Option<&'a Path>,
}

impl Session {
    /// Starts the session and waits until PipeWire answers `pw-dump`.
    pub fn start() -> Self {
        Self::start_with(SessionOptions::default())
    }

    /// [`Session::start`] with `options`.
    pub fn start_with(options: SessionOptions) -> Self {
        logind_state_dirs();
        let dir = tempfile::tempdir().expect("temporary directory");
        let runtime = options
            .runtime_dir
            .map_or_else(|| dir.path().join("runtime"), Path::to_owned);
        std::fs::create_dir_all(&runtime).expect("runtime dir");
        std::fs::set_permissions(
            &runtime,
            std::os::unix::fs::PermissionsExt::from_mode(0o700),
        )
        .expect("chmod runtime dir");
        // A previous daemon's socket in a fixed directory would answer the
        // wait below at once, and WirePlumber would quit ("Failed to
        // connect to PipeWire").
        for stale in ["pipewire-0", "pipewire-0.lock"] {
            let _ = std::fs::remove_file(runtime.join(stale));
        }
        let config = options
            .config_home
            .map_or_else(|| dir.path().join("config"), Path::to_owned);
        let bus = Bus::start();
        // Services the bus starts on demand (WirePlumber asks the portal's
        // permission store) get the session's directories, not the caller's
        // home.
        let home = dir.path().join("home");
        std::fs::create_dir_all(&home).expect("home dir");
        let set = |k: &str, v: &Path| format!("{k},{}", v.display());
        let _ = Command::new("dbus-send")
            .args([
                &format!("--bus={}", bus.address),
                "--print-reply",
                "--dest=org.freedesktop.DBus",
                "/org/freedesktop/DBus",
                "org.freedesktop.DBus.UpdateActivationEnvironment",
            ])
            .arg(format!(
                "dict:string:string:{},{},{},{}",
                set("HOME", &home),
                set("XDG_DATA_HOME", &dir.path().join("data")),
                set("XDG_CONFIG_HOME", &config),
                set("XDG_RUNTIME_DIR", &runtime),
            ))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status();
        let clients = Clients {
            prefix: Vec::new(),
            env: session_env(dir.path(), &runtime, &config, &bus.address),
            scratch: dir.path().to_owned(),
        };
        let pipewire = spawn_logged(&clients, "pipewire");
        wait_for(
            "PipeWire to answer pw-dump",
            Duration::from_secs(20),
            || clients.dump(),
        );
        let wireplumber = spawn_logged(&clients, "wireplumber");
        Self {
            _wireplumber: wireplumber,
            _pipewire: pipewire,
            bus,
            dir,
            clients,
        }
    }

    pub fn runtime_dir(&self) -> PathBuf {
        PathBuf::from(self.clients.var("XDG_RUNTIME_DIR"))
    }

    /// The log of the session's `program` ("pipewire", "wireplumber").
    pub fn log_path(&self, program: &str) -> PathBuf {
        self.clients.scratch.join(format!("{program}.log"))
    }

    /// Waits until WirePlumber is a client of the daemon (it then has
    /// loaded its configuration and starts its monitors); false after
    /// `timeout`.
    pub fn wait_wireplumber(&self, timeout: Duration) -> bool {
        let t0 = Instant::now();
        while !self.objects().iter().any(|o| {
            o["type"] == "PipeWire:Interface:Client"
                && o["info"]["props"]["application.name"] == "WirePlumber"
        }) {
            if t0.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        true
    }
}

impl Clients {
    /// Clients of user `name`'s own session (uid `uid`), as systemd's user
    /// manager runs it: `/run/user/UID` and its bus. The readers write into
    /// `scratch`, which the user must be able to write.
    pub fn user(name: &str, uid: u32, scratch: &Path) -> Self {
        let runtime = format!("/run/user/{uid}");
        Self {
            prefix: ["runuser", "-p", "-u", name, "--"]
                .map(str::to_owned)
                .to_vec(),
            env: vec![
                (
                    "DBUS_SESSION_BUS_ADDRESS".into(),
                    format!("unix:path={runtime}/bus"),
                ),
                ("XDG_RUNTIME_DIR".into(), runtime),
            ],
            scratch: scratch.to_owned(),
        }
    }

    /// `program` set up as a client of this session (runtime dir, bus,
    /// config dirs). As another user, `runuser -p` keeps the environment
    /// set here, and only that: callers add to it with `Command::env`.
    pub fn command(&self, program: impl AsRef<std::ffi::OsStr>) -> Command {
        let mut cmd = match self.prefix.split_first() {
            None => Command::new(program),
            Some((first, rest)) => {
                let mut cmd = Command::new(first);
                cmd.args(rest).arg(program);
                cmd.env_clear().env("PATH", "/usr/sbin:/usr/bin:/sbin:/bin");
                cmd
            }
        };
        cmd.envs(self.env.iter().map(|(k, v)| (k, v)))
            .env_remove("PIPEWIRE_REMOTE")
            .env_remove("PIPEWIRE_RUNTIME_DIR")
            .env_remove("DISPLAY")
            .env_remove("WAYLAND_DISPLAY");
        cmd
    }

    /// The session bus's address.
    pub fn bus_address(&self) -> &str {
        self.var("DBUS_SESSION_BUS_ADDRESS")
    }

    /// A variable of the clients' environment ("" when unset).
    fn var(&self, name: &str) -> &str {
        self.env
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
            .unwrap_or_default()
    }

    /// Every object `pw-dump` lists (none while PipeWire does not answer).
    pub fn objects(&self) -> Vec<serde_json::Value> {
        match self.dump() {
            Some(serde_json::Value::Array(objects)) => objects,
            _ => Vec::new(),
        }
    }

    /// True when `name` has an owner on the session bus.
    fn has_owner(&self, name: &str) -> bool {
        self.command("dbus-send")
            .args([
                "--session",
                "--print-reply",
                "--dest=org.freedesktop.DBus",
                "/org/freedesktop/DBus",
                "org.freedesktop.DBus.NameHasOwner",
                &format!("string:{name}"),
            ])
            .output()
            .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).contains("boolean true"))
    }

    /// Stores the camera permission "yes" for unsandboxed programs (app id
    /// "") and for Chromium, starting the permission store by D-Bus
    /// activation: the portal then asks no one. In a user session run by
    /// systemd Chromium moves itself into a scope
    /// (`app-org.chromium.Chromium-PID.scope`) and the portal takes its app
    /// id from that ("Assigning app ID \"org.chromium.Chromium\""), so "" does
    /// not cover it there.
    pub fn grant_camera(&self) {
        for app_id in ["", CHROMIUM_APP_ID] {
            self.grant_camera_to(app_id);
        }
    }

    fn grant_camera_to(&self, app_id: &str) {
        let t0 = Instant::now();
        loop {
            let out = self
                .command("dbus-send")
                .args([
                    "--session",
                    "--print-reply",
                    "--dest=org.freedesktop.impl.portal.PermissionStore",
                    "/org/freedesktop/impl/portal/PermissionStore",
                    "org.freedesktop.impl.portal.PermissionStore.SetPermission",
                    "string:devices",
                    "boolean:true",
                    "string:camera",
                    &format!("string:{app_id}"),
                    "array:string:yes",
                ])
                .output()
                .expect("run dbus-send");
            if out.status.success() {
                return;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "the permission store did not grant the camera to app id {app_id:?} in 60 s: \
                 dbus-send {}: {}; store running: {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).trim(),
                self.has_owner("org.freedesktop.impl.portal.PermissionStore")
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Waits until the portal (started by D-Bus activation, or by the
    /// caller) exports the camera portal; `log` is its log, for the message.
    pub fn wait_camera_portal(&self, log: impl Fn() -> String) {
        let t0 = Instant::now();
        while !self
            .command("dbus-send")
            .args([
                "--session",
                "--print-reply",
                "--dest=org.freedesktop.portal.Desktop",
                "/org/freedesktop/portal/desktop",
                "org.freedesktop.DBus.Properties.Get",
                "string:org.freedesktop.portal.Camera",
                "string:version",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|st| st.success())
        {
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "no camera portal after 60 s; its log:\n{}",
                log()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// `pw-dump`'s JSON, None while PipeWire does not answer.
    fn dump(&self) -> Option<serde_json::Value> {
        let out = self
            .command("pw-dump")
            .stderr(Stdio::null())
            .output()
            .ok()?;
        if !out.status.success() {
            return None;
        }
        serde_json::from_slice(&out.stdout).ok()
    }

    /// Properties of every node, from `pw-dump`.
    pub fn nodes(&self) -> Vec<HashMap<String, serde_json::Value>> {
        self.objects()
            .iter()
            .filter(|o| o["type"] == "PipeWire:Interface:Node")
            .filter_map(|o| o["info"]["props"].as_object())
            .map(|p| p.iter().map(|(k, v)| (k.clone(), v.clone())).collect())
            .collect()
    }

    /// The nodes PipeWire lists as an SDI camera (media.role Camera and a
    /// name, description or V4L2 card of SDI's): the fed camera, and the
    /// loopback node unless SDI's WirePlumber rule hides it.
    pub fn sdi_cameras(&self) -> Vec<HashMap<String, serde_json::Value>> {
        self.nodes()
            .into_iter()
            .filter(|p| {
                let text = |k: &str| p.get(k).and_then(|v| v.as_str()).unwrap_or("").to_owned();
                p.get("media.role").and_then(|v| v.as_str()) == Some("Camera")
                    && (text("node.name").starts_with("sdi-")
                        || text("node.description").contains("SDI")
                        || text("api.v4l2.cap.card").contains("SDI"))
            })
            .collect()
    }

    /// The video nodes, their formats and the links between them, from
    /// `pw-dump`: what a failed read is explained with.
    pub fn video_graph(&self) -> String {
        let objects = self.objects();
        let mut lines = Vec::new();
        for o in &objects {
            let info = &o["info"];
            let props = &info["props"];
            let class = props["media.class"].as_str().unwrap_or("");
            if o["type"] == "PipeWire:Interface:Node" && class.contains("Video") {
                lines.push(format!(
                    "node {} {} of {} ({class}, {}): Format {} EnumFormat {}",
                    o["id"],
                    props["node.name"].as_str().unwrap_or("?"),
                    props["application.name"].as_str().unwrap_or("?"),
                    info["state"].as_str().unwrap_or("?"),
                    info["params"]["Format"],
                    info["params"]["EnumFormat"]
                ));
            } else if o["type"] == "PipeWire:Interface:Link" {
                lines.push(format!(
                    "link {}: node {} -> node {} ({}{})",
                    o["id"],
                    info["output-node-id"],
                    info["input-node-id"],
                    info["state"].as_str().unwrap_or("?"),
                    info["error"]
                        .as_str()
                        .map(|e| format!(", error {e}"))
                        .unwrap_or_default()
                ));
            }
        }
        lines.join("\n")
    }

    /// The state of the node named `name` ("suspended", "idle", "running",
    /// "error"), once it exists.
    pub fn node_state(&self, name: &str) -> Option<String> {
        self.objects().iter().find_map(|o| {
            let info = &o["info"];
            (o["type"] == "PipeWire:Interface:Node" && info["props"]["node.name"] == name)
                .then(|| info["state"].as_str().unwrap_or("").to_owned())
        })
    }

    /// The properties of the node named `name`, once it exists.
    pub fn node(&self, name: &str) -> Option<HashMap<String, serde_json::Value>> {
        self.nodes()
            .into_iter()
            .find(|p| p.get("node.name").and_then(|v| v.as_str()) == Some(name))
    }

    /// Reads `frames` buffers of `caps` (e.g. "video/x-raw,format=RGB") from
    /// node `target` with `gst-launch-1.0 pipewiresrc`; returns the raw bytes.
    pub fn read_frames(&self, target: &str, caps: &str, frames: u32, timeout: Duration) -> Vec<u8> {
        self.try_read_frames(target, caps, frames, timeout)
            .unwrap_or_else(|e| panic!("{e}"))
    }

    /// [`Clients::read_frames`], with a failed read as an error that says
    /// how pipewiresrc negotiated and what the video graph is now.
    pub fn try_read_frames(
        &self,
        target: &str,
        caps: &str,
        frames: u32,
        timeout: Duration,
    ) -> Result<Vec<u8>, String> {
        let out = self.scratch.join(format!("{target}.raw"));
        let _ = std::fs::remove_file(&out);
        let pipeline = format!(
            "pipewiresrc target-object={target} num-buffers={frames} ! {caps} ! filesink location={}",
            out.display()
        );
        // pipewiresrc's own account of the negotiation, printed on failure.
        let gst_log = self.scratch.join(format!("{target}.gst.log"));
        let _ = std::fs::remove_file(&gst_log);
        let mut child = self
            .command("gst-launch-1.0")
            .env("GST_DEBUG", "pipewiresrc:5")
            .env("GST_DEBUG_NO_COLOR", "1")
            .env("GST_DEBUG_FILE", &gst_log)
            .arg("-q")
            .args(pipeline.split(' '))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start gst-launch-1.0");
        let status = wait_child(&mut child, timeout);
        let mut err = String::new();
        if let Some(mut e) = child.stderr.take() {
            let _ = e.read_to_string(&mut err);
        }
        if !status.is_some_and(|s| s.success()) {
            let negotiation: Vec<String> = std::fs::read_to_string(&gst_log)
                .unwrap_or_default()
                .lines()
                .filter(|l| {
                    ["caps", "format", "target", "state", "error", "node"]
                        .iter()
                        .any(|w| l.contains(w))
                })
                .map(str::to_owned)
                .collect();
            return Err(format!(
                "gst-launch-1.0 {pipeline}: {status:?} (None = timeout after {timeout:?})\n{err}\n\
                 pipewiresrc's log (GST_DEBUG=pipewiresrc:5):\n{}\n\
                 the video graph now:\n{}",
                negotiation.join("\n"),
                self.video_graph()
            ));
        }
        std::fs::read(&out).map_err(|e| format!("read the frames gst-launch wrote: {e}"))
    }

    /// Starts a reader of node `target` that runs until dropped, hashing
    /// each `frame_bytes` frame it gets.
    pub fn stream_frames(&self, target: &str, caps: &str, frame_bytes: usize) -> FrameStream {
        let mut child = self
            .command("gst-launch-1.0")
            .arg("-q")
            .args(format!("pipewiresrc target-object={target} ! {caps} ! fdsink fd=1").split(' '))
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start gst-launch-1.0");
        let mut out = child.stdout.take().expect("gst-launch stdout");
        let crcs = Arc::new(Mutex::new(Vec::new()));
        let c = crcs.clone();
        std::thread::spawn(move || {
            let mut frame = vec![0; frame_bytes];
            while out.read_exact(&mut frame).is_ok() {
                let crc = format!("{:08x}", crc32fast::hash(&frame));
                c.lock().expect("crc lock").push(crc);
            }
        });
        FrameStream {
            child: Reaped(child),
            crcs,
        }
    }

    /// Starts a reader that runs until killed (`pipewiresrc ! fakesink`).
    pub fn reader(&self, target: &str, caps: &str) -> Reaped {
        Reaped(
            self.command("gst-launch-1.0")
                .arg("-q")
                .args(format!("pipewiresrc target-object={target} ! {caps} ! fakesink").split(' '))
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("start gst-launch-1.0"),
        )
    }
}

/// WirePlumber 0.4.13 quits ("failed to start systemd logind monitor: -2")
/// when logind's state directories are missing, as in the VM (no systemd):
/// PipeWire then runs without a session manager, a client's own nodes
/// (the camera's) are still listed, but no stream is ever linked and
/// `pipewiresrc` fails ("Failed to set pipeline to PAUSED"). Makes them
/// where they are missing (they exist wherever logind runs).
pub fn logind_state_dirs() {
    for d in ["seats", "sessions", "users", "machines"] {
        let d = Path::new("/run/systemd").join(d);
        if !d.is_dir() {
            std::fs::create_dir_all(&d)
                .unwrap_or_else(|e| panic!("mkdir {} for WirePlumber: {e}", d.display()));
        }
    }
}

/// A portal backend that claims `Access` for the desktop [`TEST_DESKTOP`]
/// and never runs: with the permission stored beforehand
/// ([`Clients::grant_camera`]) the portal exports the camera portal and
/// asks no one.
pub const TEST_PORTAL: &str = "[portal]\nDBusName=org.freedesktop.impl.portal.desktop.sditest\n\
     Interfaces=org.freedesktop.impl.portal.Access;\nUseIn=sditest\n";
/// The app id the portal gives Chromium in a systemd user session.
pub const CHROMIUM_APP_ID: &str = "org.chromium.Chromium";
/// The name of [`TEST_PORTAL`]'s file in a portals directory.
const TEST_PORTAL_FILE: &str = "sdi-test.portal";
/// `XDG_CURRENT_DESKTOP` under which the portal uses [`TEST_PORTAL`].
pub const TEST_DESKTOP: &str = "sditest";

/// Makes `parent/portals` with [`TEST_PORTAL`] in it, for the portal's
/// `XDG_DESKTOP_PORTAL_DIR`; returns its path.
pub fn test_portals_dir(parent: &Path) -> PathBuf {
    let dir = parent.join("portals");
    std::fs::create_dir_all(&dir).expect("portals dir");
    std::fs::write(dir.join(TEST_PORTAL_FILE), TEST_PORTAL).expect("write the .portal file");
    dir
}

/// The camera portal for a session: `xdg-desktop-portal` (Debian 12: 1.16)
/// with the permission store, killed on drop. The portal exports
/// `org.freedesktop.portal.Camera` only when some backend implements
/// `org.freedesktop.impl.portal.Access` (it asks the user there); a
/// `.portal` file in `XDG_DESKTOP_PORTAL_DIR` names one, and the camera
/// permission is stored as "yes" beforehand ([`Clients::grant_camera`]),
/// so no dialog is ever asked for and the backend need not run.
pub struct CameraPortal {
    _portal: Reaped,
}

impl CameraPortal {
    /// Programs the portal needs, if one is missing.
    pub fn missing() -> Option<String> {
        [
            "/usr/libexec/xdg-desktop-portal",
            "/usr/libexec/xdg-permission-store",
        ]
        .iter()
        .find(|p| !Path::new(p).exists())
        .map(|p| format!("{p} (apt-get install xdg-desktop-portal)"))
    }

    /// Starts the portal on the session's bus, and the permission store by
    /// D-Bus activation.
    pub fn start(s: &Session) -> Self {
        let dir = test_portals_dir(s.dir.path());
        // `--replace`: in case a portal was started by D-Bus activation
        // already (without this environment).
        let spawn = |program: &str, log: &str| {
            let log = std::fs::File::create(s.dir.path().join(log)).expect("log file");
            let mut cmd = s.command(program);
            cmd.args(["--replace", "--verbose"])
                .env("XDG_DESKTOP_PORTAL_DIR", &dir)
                .env("XDG_CURRENT_DESKTOP", TEST_DESKTOP)
                .stdout(log.try_clone().expect("log file"))
                .stderr(log);
            Reaped(
                cmd.spawn()
                    .unwrap_or_else(|e| panic!("start {program}: {e}")),
            )
        };
        // The permission store only by D-Bus activation (WirePlumber's
        // camera lookup or this call start it once, with the session's
        // environment, Session::start): a second store started here with
        // `--replace` shared its database directory, and one read the
        // other's half-written file ("Unable to load db file devices:
        // invalid gvdb header", 3 runs in 7), refusing every call.
        s.grant_camera();
        // The portal is waited for until it owns its name: a call before
        // that would start another copy by D-Bus activation, without this
        // environment.
        let portal = spawn("/usr/libexec/xdg-desktop-portal", "portal.log");
        wait_for("the portal", Duration::from_secs(60), || {
            s.has_owner("org.freedesktop.portal.Desktop").then_some(())
        });
        s.wait_camera_portal(|| {
            std::fs::read_to_string(s.dir.path().join("portal.log")).unwrap_or_default()
        });
        Self { _portal: portal }
    }
}

/// Starts `program` as a client of the session, its stderr to
/// `program.log` in the clients' scratch directory.
fn spawn_logged(clients: &Clients, program: &str) -> Reaped {
    let log =
        std::fs::File::create(clients.scratch.join(format!("{program}.log"))).expect("log file");
    Reaped(
        clients
            .command(program)
            // Warnings and errors: WirePlumber's reasons for a node it did
            // not make, the v4l2 plugin's for a failed link.
            .env("WIREPLUMBER_DEBUG", "2")
            .env("PIPEWIRE_DEBUG", "2")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("start {program}: {e}")),
    )
}

/// Waits for `child` at most `timeout`; kills it and returns None on timeout.
fn wait_child(child: &mut Child, timeout: Duration) -> Option<std::process::ExitStatus> {
    let t0 = Instant::now();
    loop {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        if t0.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The private session's environment under `dir`, with its runtime and
/// configuration directories.
fn session_env(dir: &Path, runtime: &Path, config: &Path, bus: &str) -> Vec<(String, String)> {
    let at = |sub: &str| dir.join(sub).display().to_string();
    vec![
        ("XDG_RUNTIME_DIR".into(), runtime.display().to_string()),
        ("XDG_CONFIG_HOME".into(), config.display().to_string()),
        ("XDG_STATE_HOME".into(), at("state")),
        ("XDG_DATA_HOME".into(), at("data")),
        ("DBUS_SESSION_BUS_ADDRESS".into(), bus.to_owned()),
    ]
}

/// The per-frame lines logged with `RUST_LOG=sdid::pipewire::frames=trace`
/// ("published stream=... crc32=..."), read from the log file that the
/// session's sdids and the camera process they start (which inherits their
/// stderr and outlives them) append to.
#[derive(Clone)]
pub struct FrameLog {
    path: PathBuf,
}

impl FrameLog {
    /// The log at `path` (opened for appending by [`FrameLog::writer`]).
    pub fn file(path: PathBuf) -> Self {
        Self { path }
    }

    /// Where the log is.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A handle appending to the log, for a child's stderr.
    pub fn writer(&self) -> std::fs::File {
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .expect("open the log for appending")
    }

    /// Published frames so far, as key=value fields.
    pub fn published(&self) -> Vec<HashMap<String, String>> {
        self.text().lines().filter_map(parse_published).collect()
    }

    /// Asserts that each frame of `crcs` (CRC-32s of frames a reader got)
    /// was logged as published on `stream` in `format` and `mode`, and that
    /// more than half of them differ (the stream moves). `what` names the
    /// reader in the message. Waits up to 10 s for the lines: the camera
    /// logs a frame before it queues the buffer.
    pub fn assert_published(
        &self,
        crcs: &[String],
        stream: &str,
        format: &str,
        mode: &str,
        what: &str,
    ) {
        let published = |c: &String| {
            self.published().iter().any(|p| {
                p.get("crc32") == Some(c)
                    && p.get("stream").map(String::as_str) == Some(stream)
                    && p.get("format").map(String::as_str) == Some(format)
                    && p.get("mode").map(String::as_str) == Some(mode)
            })
        };
        let t0 = Instant::now();
        while !crcs.iter().all(published) && t0.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(100));
        }
        let missing: Vec<&String> = crcs.iter().filter(|c| !published(c)).collect();
        assert!(
            missing.is_empty(),
            "{what}: {} of {} frames read were not published on {stream} as {format} in mode {mode}: {missing:?}",
            missing.len(),
            crcs.len()
        );
        let distinct: std::collections::HashSet<&String> = crcs.iter().collect();
        assert!(
            distinct.len() * 2 > crcs.len(),
            "{what}: only {} distinct frames of {}",
            distinct.len(),
            crcs.len()
        );
    }

    /// Everything logged so far.
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&std::fs::read(&self.path).unwrap_or_default()).into_owned()
    }
}

/// The mode a camera node shows, from its description "SDI camera (MODE)".
pub fn camera_mode(props: &HashMap<String, serde_json::Value>) -> Option<String> {
    props
        .get("node.description")?
        .as_str()?
        .strip_prefix("SDI camera (")?
        .strip_suffix(')')
        .map(str::to_owned)
}

/// A reader that runs until dropped (`pipewiresrc ! fdsink`), keeping the
/// CRC-32 of every frame it received.
pub struct FrameStream {
    child: Reaped,
    crcs: Arc<Mutex<Vec<String>>>,
}

impl FrameStream {
    /// CRCs of the frames received so far, in order.
    pub fn crcs(&self) -> Vec<String> {
        self.crcs.lock().expect("crc lock").clone()
    }

    /// True while gst-launch runs.
    pub fn running(&mut self) -> bool {
        matches!(self.child.0.try_wait(), Ok(None))
    }
}

/// Fields of one "published" line: `... published stream="sdi-camera" crc32=0a1b2c3d`.
pub fn parse_published(line: &str) -> Option<HashMap<String, String>> {
    let rest = line.split_once(" published ")?.1;
    Some(
        rest.split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_owned(), v.trim_matches('"').to_owned()))
            .collect(),
    )
}

/// CRC-32 (as logged) of each `frame_bytes` chunk of `data`.
pub fn frame_crcs(data: &[u8], frame_bytes: usize) -> Vec<String> {
    data.chunks_exact(frame_bytes)
        .map(|f| format!("{:08x}", crc32fast::hash(f)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_published_line() {
        let l = "2026-11-24T05:41:29Z TRACE sdid::pipewire::frames: published stream=\"sdi-camera\" format=\"RGB\" mode=\"raw\" seq=2 pts_ns=9806 bytes=921600 crc32=e204d9a6";
        let f = parse_published(l).unwrap();
        assert_eq!(f["stream"], "sdi-camera");
        assert_eq!(f["crc32"], "e204d9a6");
        assert_eq!(f["pts_ns"], "9806");
        assert!(parse_published("INFO sdid: serving").is_none());
    }
}
