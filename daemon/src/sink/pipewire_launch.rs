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

/// Connects to this user's camera process, starting `program SPEC` when
/// none runs; fails with the camera's own
/// reason (e.g. "no PipeWire daemon reachable at ...").
pub fn connect(program: &Path, spec: &Spec) -> Result<Connected, String> {
    let sock = link::runtime_dir()?.join(link::SOCKET_NAME);
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
                Started::Busy => last = "another camera process is starting".into(),
            },
        }
        if Instant::now() >= deadline {
            return Err(format!(
                "the PipeWire camera process at {} did not take sdid: {last}",
                sock.display()
            ));
        }
        std::thread::sleep(RETRY);
    }
}

fn greet(stream: UnixStream, spec: &Spec) -> Result<Connected, String> {
    let io = |e: std::io::Error| format!("greeting the camera process: {e}");
    // Frames go only to a camera process of this user, as it takes them only from one.
    let peer = getsockopt(&stream, PeerCredentials)
        .map_err(|e| format!("the camera socket's peer credentials: {e}"))?;
    if peer.uid() != nix::unistd::getuid().as_raw() {
        return Err(format!(
            "the camera socket is served by uid {}, not this user",
            peer.uid()
        ));
    }
    stream.set_read_timeout(Some(CONNECT_TIMEOUT)).map_err(io)?;
    stream
        .set_write_timeout(Some(Duration::from_secs(2)))
        .map_err(io)?;
    let mut s = &stream;
    link::write(&mut s, &Message::Hello(spec.clone())).map_err(io)?;
    match link::read(&mut s) {
        Ok(Message::Ready) => {}
        Ok(Message::Refused(why)) => return Err(why),
        Ok(m) => return Err(format!("the camera process answered {m:?}")),
        Err(e) => return Err(e.to_string()),
    }
    stream.set_read_timeout(None).map_err(io)?;
    let camera_pid = u32::try_from(peer.pid()).ok();
    Ok(Connected { stream, camera_pid })
}

enum Started {
    Ready,
    Busy,
}

/// Starts the camera process and waits for its first line.
fn start(program: &Path, spec: &Spec, deadline: Instant) -> Result<Started, String> {
    let mut child = Command::new(program)
        .arg(spec.to_string())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        // Its own group: a Ctrl-C or a kill of sdid's group leaves it running.
        .process_group(0)
        .spawn()
        .map_err(|e| format!("starting {}: {e}", program.display()))?;
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
        .map_err(|_| "the PipeWire camera process did not start in time".to_string())?;
    let line = line.trim_end();
    if line == link::READY_LINE {
        tracing::info!(pid, "started the PipeWire camera process");
        Ok(Started::Ready)
    } else if line == link::BUSY_LINE {
        Ok(Started::Busy)
    } else if let Some(why) = line.strip_prefix(link::ERROR_PREFIX) {
        Err(why.to_string())
    } else {
        Err(format!(
            "the PipeWire camera process ended without a word ({line:?})"
        ))
    }
}
