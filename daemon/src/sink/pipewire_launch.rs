//! sdid's side of the camera process: find the program, connect to the
//! running one, or start it (`sdi-pipewire-camera SPEC`, in its own process
//! group so it outlives this sdid), and greet it.

use std::io::{BufRead, BufReader};
use std::os::unix::net::UnixStream;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use nix::sys::socket::{getsockopt, sockopt::PeerCredentials};

use sdi_camera_link::{self as link, Message, Spec};

pub use link::CAMERA_BUILD_PACKAGES as BUILD_PACKAGES;

/// The camera program is not installed where sdid looks for it.
#[derive(Debug, thiserror::Error)]
#[error(
    "the PipeWire camera program {program} is not installed (looked in {looked}): \
     install the sdi-pipewire-camera package, or build it with \
     `cargo build --release -p sdi-pipewire-camera` (needs {BUILD_PACKAGES})",
    program = link::CAMERA_PROGRAM
)]
pub struct NotInstalled {
    pub looked: String,
}

/// The installed camera program ([`link::camera_candidates`] from sdid's
/// own directory), or where it was looked for.
pub fn find_program() -> Result<PathBuf, NotInstalled> {
    let candidates: Vec<PathBuf> = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(link::camera_candidates))
        .map(Vec::from)
        .unwrap_or_default();
    candidates
        .iter()
        .find(|p| p.is_file())
        .cloned()
        .ok_or_else(|| NotInstalled {
            looked: candidates
                .iter()
                .filter_map(|p| p.parent())
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// The PipeWire daemon's socket for this user, if one is there: sdid does
/// not start the camera process where no PipeWire runs.
pub fn pipewire_socket() -> Option<PathBuf> {
    let remote = std::env::var_os("PIPEWIRE_REMOTE").unwrap_or_else(|| "pipewire-0".into());
    let path = PathBuf::from(remote);
    let path = match path.is_absolute() {
        true => path,
        false => PathBuf::from(std::env::var_os("XDG_RUNTIME_DIR")?).join(path),
    };
    path.exists().then_some(path)
}

/// Why sdid could not reach a camera process; the messages are what sdid's
/// log and first screen show.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// No runtime directory to hold the camera's socket.
    #[error("{0}")]
    RuntimeDir(String),
    #[error("the PipeWire camera process at {} did not take sdid: {last}", socket.display())]
    NotTaken {
        socket: PathBuf,
        #[source]
        last: GreetError,
    },
    #[error("starting {}: {source}", program.display())]
    Spawn {
        program: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("the PipeWire camera process did not start in time")]
    StartTimeout,
    /// The camera process's own reason (e.g. "no PipeWire daemon reachable at ...").
    #[error("{0}")]
    Camera(String),
    #[error("the PipeWire camera process ended without a word ({0:?})")]
    NoWord(String),
}

/// Why one greeting of a running camera process failed.
#[derive(Debug, thiserror::Error)]
pub enum GreetError {
    #[error("greeting the camera process: {0}")]
    Io(#[from] std::io::Error),
    #[error("the camera socket's peer credentials: {0}")]
    PeerCredentials(#[source] nix::Error),
    #[error("the camera socket is served by uid {0}, not this user")]
    OtherUser(u32),
    /// The camera is ending (new sizes) or busy with another sdid.
    #[error("{0}")]
    Refused(String),
    #[error("the camera process answered {0}")]
    Unexpected(String),
    #[error(transparent)]
    Link(#[from] link::LinkError),
    #[error("another camera process is starting")]
    AnotherStarting,
}

/// How long [`connect`] tries, start-up of a new camera process included.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(8);
/// Between attempts while a camera process is starting or ending.
const RETRY: Duration = Duration::from_millis(100);

/// A greeted link to the camera process.
pub struct Connected {
    pub stream: UnixStream,
    /// The camera process (from the socket's peer credentials).
    pub camera_pid: Option<u32>,
}

/// Connects to this user's process of the camera `spec` (its socket
/// named by [`Spec::names`]), starting `program SPEC` when none runs;
/// fails with the camera's own
/// reason (e.g. "no PipeWire daemon reachable at ...").
pub fn connect(program: &Path, spec: &Spec) -> Result<Connected, ConnectError> {
    let sock = link::runtime_dir()
        .map_err(ConnectError::RuntimeDir)?
        .join(spec.names().socket());
    let deadline = Instant::now() + CONNECT_TIMEOUT;
    let mut last;
    loop {
        match UnixStream::connect(&sock) {
            Ok(s) => match greet(s, spec) {
                Ok(c) => return Ok(c),
                // Refused: the camera is ending (new sizes) or busy with another sdid.
                Err(e) => last = e,
            },
            Err(_) => match start(program, spec, deadline)? {
                Started::Ready => continue,
                Started::Busy => last = GreetError::AnotherStarting,
            },
        }
        if Instant::now() >= deadline {
            return Err(ConnectError::NotTaken { socket: sock, last });
        }
        std::thread::sleep(RETRY);
    }
}

fn greet(stream: UnixStream, spec: &Spec) -> Result<Connected, GreetError> {
    // Frames go only to a camera process of this user, as it takes them only from one.
    let peer = getsockopt(&stream, PeerCredentials).map_err(GreetError::PeerCredentials)?;
    if peer.uid() != nix::unistd::getuid().as_raw() {
        return Err(GreetError::OtherUser(peer.uid()));
    }
    hello(stream, spec)
}

/// Says Hello on `stream` to a camera process whose peer was checked by
/// the caller, and waits for its Ready.
pub fn hello(stream: UnixStream, spec: &Spec) -> Result<Connected, GreetError> {
    let peer = getsockopt(&stream, PeerCredentials).map_err(GreetError::PeerCredentials)?;
    stream.set_read_timeout(Some(CONNECT_TIMEOUT))?;
    stream.set_write_timeout(Some(Duration::from_secs(2)))?;
    let mut s = &stream;
    link::write(&mut s, &Message::Hello(spec.clone()))?;
    match link::read(&mut s)? {
        Message::Ready => {}
        Message::Refused(why) => return Err(GreetError::Refused(why)),
        m => return Err(GreetError::Unexpected(format!("{m:?}"))),
    }
    stream.set_read_timeout(None)?;
    let camera_pid = u32::try_from(peer.pid()).ok();
    Ok(Connected { stream, camera_pid })
}

enum Started {
    Ready,
    Busy,
}

/// Starts the camera process and waits for its first line.
fn start(program: &Path, spec: &Spec, deadline: Instant) -> Result<Started, ConnectError> {
    let mut child = Command::new(program)
        .arg(spec.to_string())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        // Its own group: a Ctrl-C or a kill of sdid's group leaves it running.
        .process_group(0)
        .spawn()
        .map_err(|source| ConnectError::Spawn {
            program: program.to_owned(),
            source,
        })?;
    let pid = child.id();
    let (tx, rx) = mpsc::channel();
    if let Some(out) = child.stdout.take() {
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(out).read_line(&mut line);
            let _ = tx.send(line);
        });
    }
    // Reaps it whenever it ends (it may outlive the wait below by hours).
    let _ = std::thread::Builder::new()
        .name("sdid-camera-reap".into())
        .spawn(move || match child.wait() {
            Ok(status) => tracing::debug!(pid, %status, "PipeWire camera process ended"),
            Err(e) => tracing::debug!(pid, "waiting for the PipeWire camera process: {e}"),
        });
    let wait = deadline.saturating_duration_since(Instant::now());
    let line = rx
        .recv_timeout(wait)
        .map_err(|_| ConnectError::StartTimeout)?;
    let line = line.trim_end();
    if line == link::READY_LINE {
        tracing::info!(pid, "started the PipeWire camera process");
        Ok(Started::Ready)
    } else if line == link::BUSY_LINE {
        Ok(Started::Busy)
    } else if let Some(why) = line.strip_prefix(link::ERROR_PREFIX) {
        Err(ConnectError::Camera(why.to_string()))
    } else {
        Err(ConnectError::NoWord(line.to_string()))
    }
}
