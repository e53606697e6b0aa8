//! The system service's PipeWire cameras: sdid as root has no PipeWire of
//! its own, so the camera process of each user's session
//! (`sdi-pipewire-camera --system-feed`, the user unit
//! `sdi-pipewire-camera.service`) connects to sdid's feed socket in its
//! runtime directory and is fed like the camera sdid starts in a session.
//! Each camera has its feed socket ([`sdi_camera_link::Names::system_feed`]:
//! `camera-feed.sock` for a lone camera, `camera-feed-SERIAL.sock` for each
//! of several), and the user's camera program serves every one it finds.
//!
//! Trust: the socket is 0660 in `RuntimeDirectory=sdi` (root:sdi 0750), so
//! only members of the group sdi, who may control the camera anyway, get
//! its pictures; whatever a connection sends is read as hostile input
//! (`sdi_camera_link`'s bounded messages). The camera takes frames there
//! only from root, so no other user can feed it.

use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver};
use std::sync::{Arc, Mutex};

use nix::sys::socket::{getsockopt, sockopt::PeerCredentials};

use sdi_camera_link::Spec;
use sdi_core::mode::ModeId;

use super::pipewire::PipewireSink;
use super::pipewire_launch as launch;
use super::{Sink, SinkError, SinkInfo, SinkKindName};
use crate::out_frame::OutFrame;

/// The feed socket could not be set up.
#[derive(Debug, thiserror::Error)]
#[error("the PipeWire camera feed socket {}: {source}", path.display())]
pub struct ListenError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// The cameras of users' sessions, fed the same pictures (each rendered
/// once per frame: [`OutFrame`]).
pub struct SystemFeed {
    path: PathBuf,
    arrived: Receiver<PipewireSink>,
    cameras: Vec<PipewireSink>,
    /// The mode new cameras are greeted with (the accept thread's copy).
    mode: Arc<Mutex<ModeId>>,
    spec: Spec,
}

/// The runtime directory systemd made for sdid (`RuntimeDirectory=`), when
/// sdid runs as a service without a user session: where the feed goes. A
/// root sdid started outside systemd (D-Bus activation without it) uses
/// `/run/sdi` when it exists.
pub fn runtime_directory() -> Option<PathBuf> {
    if std::env::var_os("XDG_RUNTIME_DIR").is_some() {
        return None;
    }
    match std::env::var_os("RUNTIME_DIRECTORY") {
        // systemd lists several, separated by ':', when a unit names several.
        Some(dir) => Some(PathBuf::from(dir.to_str()?.split(':').next()?)),
        None => {
            let dir = Path::new(sdi_camera_link::SYSTEM_RUNTIME_DIR);
            (nix::unistd::getuid().is_root() && dir.is_dir()).then(|| dir.to_owned())
        }
    }
}

impl SystemFeed {
    /// Listens in `dir` on the feed socket of the camera `spec` for the
    /// users' camera processes.
    pub fn listen(dir: &Path, spec: Spec) -> Result<Self, ListenError> {
        let path = dir.join(spec.names().system_feed());
        let err = |source| ListenError {
            path: path.clone(),
            source,
        };
        // A socket left by a killed sdid (the directory is sdid's own).
        let _ = std::fs::remove_file(&path);
        let listener = UnixListener::bind(&path).map_err(err)?;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o660)).map_err(err)?;
        let shared_mode = Arc::new(Mutex::new(spec.mode));
        let (tx, arrived) = mpsc::channel();
        let (m, greeting) = (shared_mode.clone(), spec.clone());
        let socket = path.clone();
        std::thread::Builder::new()
            .name("sdid-camera-feed".into())
            .spawn(move || {
                for s in listener.incoming() {
                    let Ok(s) = s else { continue };
                    let mut spec = greeting.clone();
                    spec.mode = *m.lock().unwrap_or_else(|e| e.into_inner());
                    // Greeted here, not on the output thread: a peer that
                    // never answers delays only the next greeting.
                    match greet(s, spec, &socket) {
                        Ok(camera) => {
                            if tx.send(camera).is_err() {
                                break;
                            }
                        }
                        Err(e) => tracing::warn!("a PipeWire camera on the feed socket: {e}"),
                    }
                }
            })
            .map_err(err)?;
        tracing::info!(socket = %path.display(), "feeding the PipeWire cameras of users' sessions");
        Ok(Self {
            path,
            arrived,
            cameras: Vec::new(),
            mode: shared_mode,
            spec,
        })
    }

    /// Cameras connected since the last frame join the set.
    fn take_arrivals(&mut self) {
        // A camera greeted with an older mode follows the next frame's.
        self.cameras.extend(self.arrived.try_iter());
    }

    /// Feeds every camera with `f`, dropping those whose link is gone.
    fn each(&mut self, mut f: impl FnMut(&mut PipewireSink) -> Result<(), SinkError>) {
        self.take_arrivals();
        self.cameras.retain_mut(|c| match f(c) {
            Ok(()) => true,
            Err(e) => {
                tracing::info!(pid = ?c.camera_pid(), "a user's PipeWire camera left: {e}");
                false
            }
        });
    }
}

/// Greets a camera process that connected to the feed socket.
fn greet(s: UnixStream, spec: Spec, socket: &Path) -> Result<PipewireSink, SinkError> {
    let peer =
        getsockopt(&s, PeerCredentials).map_err(|e| SinkError::Io(std::io::Error::from(e)))?;
    let c = launch::hello(s, &spec).map_err(|last| {
        SinkError::Camera(launch::ConnectError::NotTaken {
            socket: socket.to_owned(),
            last,
        })
    })?;
    tracing::info!(
        uid = peer.uid(),
        pid = peer.pid(),
        "a user's PipeWire camera connected"
    );
    PipewireSink::over(c, spec)
}

impl Sink for SystemFeed {
    fn info(&self) -> SinkInfo {
        SinkInfo {
            kind: SinkKindName::Pipewire,
            device: format!(
                "PipeWire node \"{}\" in each user session whose camera connects to {}",
                self.spec.names().view_node(),
                self.path.display()
            ),
            format: "YUYV".into(),
            width: self.spec.view_width,
            height: self.spec.view_height,
        }
    }

    fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError> {
        if self.spec.mode != frame.mode {
            self.spec.mode = frame.mode;
            *self.mode.lock().unwrap_or_else(|e| e.into_inner()) = frame.mode;
        }
        self.each(|c| c.write(frame));
        Ok(())
    }

    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
        self.each(|c| c.write_no_signal(timestamp_us));
        Ok(())
    }

    /// Streams readers started, over every user's camera.
    fn watchers(&mut self) -> Option<u32> {
        self.take_arrivals();
        Some(self.cameras.iter_mut().filter_map(|c| c.watchers()).sum())
    }
}
