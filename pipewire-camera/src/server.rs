//! The camera process (`sdi-pipewire-camera SPEC`): owns the PipeWire
//! nodes, so a reader keeps its stream while sdid restarts, and takes frames
//! from one sdid at a time over [`sdi_camera_link`].
//!
//! While no sdid is connected it shows the "no signal" card 5 times a
//! second. It exits when sdid has been gone for [`LINGER`] and no reader
//! streams, when sdid sends `Quit`, when a new sdid needs other sizes, or
//! when the PipeWire connection is lost.

use std::ffi::OsString;
use std::fs::OpenOptions;
use std::io::Write;
use std::os::fd::AsFd;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::fcntl::{Flock, FlockArg};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::socket::{getsockopt, sockopt::PeerCredentials};

use sdi_camera_link::{self as link, LinkError, Message, Port, Spec, State, Wire, LINGER};

use crate::nodes::{monotonic_now_us, Nodes, NodesError};

/// Why the camera process stops serving; the messages are the reasons the
/// starting sdid reports (before the ready line) or the log shows.
#[derive(Debug, thiserror::Error)]
enum ServeError {
    #[error("the camera spec argument is missing")]
    NoSpec,
    /// The spec argument does not parse.
    #[error("{0}")]
    Spec(String),
    /// No runtime directory for the lock and the socket.
    #[error("{0}")]
    RuntimeDir(String),
    #[error("{}: {source}", path.display())]
    Lock {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("locking {}: {source}", path.display())]
    Locking {
        path: PathBuf,
        #[source]
        source: Errno,
    },
    #[error(transparent)]
    Nodes(#[from] NodesError),
    #[error("binding {}: {source}", path.display())]
    Bind {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {source}", path.display())]
    Socket {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("the PipeWire connection was lost")]
    ConnectionLost,
}
/// The "no signal" card's period while sdid is away (sdid's own rate).
const NO_SIGNAL_PERIOD: Duration = Duration::from_millis(200);
/// The main loop's tick: state reports, the card, the linger check (a
/// connecting sdid wakes it at once).
const TICK_MS: u16 = 100;
/// Fewest milliseconds between two state reports that only count buffers
/// (a change of format is reported at the next tick).
const STATE_PERIOD: Duration = Duration::from_millis(200);

/// Entry point of `sdi-pipewire-camera SPEC`. The first line on stdout
/// tells the sdid that started it how it went ([`link::READY_LINE`],
/// [`link::BUSY_LINE`] or [`link::ERROR_PREFIX`] and the reason).
pub fn main(spec: Option<OsString>) -> ExitCode {
    let spec = match spec
        .as_ref()
        .and_then(|s| s.to_str())
        .map(str::parse::<Spec>)
    {
        Some(Ok(s)) => s,
        Some(Err(e)) => return fail(&ServeError::Spec(e)),
        None => return fail(&ServeError::NoSpec),
    };
    match run(spec) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(&e),
    }
}

/// Set once the ready line went out: later failures are logged, earlier
/// ones go back to the starting sdid on stdout (which says what it does
/// next, e.g. falls back to y4m).
static SERVING: AtomicBool = AtomicBool::new(false);

fn fail(why: &ServeError) -> ExitCode {
    if SERVING.load(Ordering::Relaxed) {
        tracing::warn!("PipeWire camera: {why}");
    } else {
        announce(&format!("{}{why}", link::ERROR_PREFIX));
        tracing::debug!("PipeWire camera: {why}");
    }
    ExitCode::FAILURE
}

fn announce(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

fn run(spec: Spec) -> Result<(), ServeError> {
    let dir = link::runtime_dir().map_err(ServeError::RuntimeDir)?;
    let lock_path = dir.join(link::LOCK_NAME);
    let lock_file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .mode(0o600)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(&lock_path)
        .map_err(|source| ServeError::Lock {
            path: lock_path.clone(),
            source,
        })?;
    let _lock = match Flock::lock(lock_file, FlockArg::LockExclusiveNonblock) {
        Ok(l) => l,
        Err((_, Errno::EWOULDBLOCK)) => {
            // Another camera process runs: the sdid that started this one connects to it.
            announce(link::BUSY_LINE);
            return Ok(());
        }
        Err((_, source)) => {
            return Err(ServeError::Locking {
                path: lock_path,
                source,
            })
        }
    };
    let nodes = Arc::new(Nodes::open(&spec)?);
    let sock = dir.join(link::SOCKET_NAME);
    // Left over from a camera that was killed (we hold the lock now).
    let _ = std::fs::remove_file(&sock);
    let listener = UnixListener::bind(&sock).map_err(|source| ServeError::Bind {
        path: sock.clone(),
        source,
    })?;
    let _ = std::fs::set_permissions(&sock, std::fs::Permissions::from_mode(0o600));
    listener
        .set_nonblocking(true)
        .map_err(|source| ServeError::Socket {
            path: sock.clone(),
            source,
        })?;
    tracing::info!(socket = %sock.display(), spec = %spec, "PipeWire camera serving");
    announce(link::READY_LINE);
    SERVING.store(true, Ordering::Relaxed);
    let r = serve(&listener, &nodes);
    let _ = std::fs::remove_file(&sock);
    r
}

/// The connected sdid.
struct Feed {
    writer: Arc<Mutex<UnixStream>>,
    /// Set once `Ready` is sent: state reports only follow it.
    greeted: Arc<AtomicBool>,
    done: Arc<AtomicBool>,
    reader: JoinHandle<()>,
    reported: Option<State>,
    reported_at: Instant,
}

fn serve(listener: &UnixListener, nodes: &Arc<Nodes>) -> Result<(), ServeError> {
    let quit = Arc::new(AtomicBool::new(false));
    let mut feed: Option<Feed> = None;
    let mut away_since = Instant::now();
    let mut card_at = Instant::now();
    loop {
        let mut fds = [PollFd::new(listener.as_fd(), PollFlags::POLLIN)];
        let _ = poll(&mut fds, PollTimeout::from(TICK_MS));
        match listener.accept() {
            Ok((s, _)) => {
                if let Some(f) = accept(s, nodes, &quit, feed.as_ref()) {
                    feed = Some(f);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => tracing::warn!("accepting sdid: {e}"),
        }
        if nodes.broken() {
            return Err(ServeError::ConnectionLost);
        }
        if quit.load(Ordering::Acquire) {
            tracing::info!("PipeWire camera: asked to quit");
            return Ok(());
        }
        if feed
            .as_ref()
            .is_some_and(|f| f.done.load(Ordering::Acquire))
        {
            if let Some(f) = feed.take() {
                let _ = f.reader.join();
            }
            away_since = Instant::now();
            tracing::info!("sdid went away: showing the no-signal card");
        }
        let state = nodes.state();
        match &mut feed {
            Some(f) if f.greeted.load(Ordering::Acquire) => {
                let changed = f.reported.is_none_or(|r| {
                    (r.view, r.data) != (state.view, state.data)
                        || (r != state && f.reported_at.elapsed() >= STATE_PERIOD)
                });
                if changed {
                    let mut w = f.writer.lock().unwrap_or_else(|e| e.into_inner());
                    // A failed write: the reader thread sees the link close.
                    let _ = link::write(&mut *w, &Message::State(state));
                    f.reported = Some(state);
                    f.reported_at = Instant::now();
                }
            }
            Some(_) => {}
            None => {
                if card_at.elapsed() >= NO_SIGNAL_PERIOD {
                    card_at = Instant::now();
                    nodes.no_signal(monotonic_now_us());
                }
                if away_since.elapsed() >= LINGER && state.view.is_none() && state.data.is_none() {
                    tracing::info!(
                        "PipeWire camera: no sdid for {} s and no reader: exiting",
                        LINGER.as_secs()
                    );
                    return Ok(());
                }
            }
        }
    }
}

/// Takes `s` as the feeding sdid, unless it is another user's or one
/// already feeds.
fn accept(
    s: UnixStream,
    nodes: &Arc<Nodes>,
    quit: &Arc<AtomicBool>,
    current: Option<&Feed>,
) -> Option<Feed> {
    match getsockopt(&s, PeerCredentials) {
        Ok(c) if c.uid() == nix::unistd::getuid().as_raw() => {}
        Ok(c) => {
            tracing::warn!(uid = c.uid(), "refusing a connection from another user");
            return None;
        }
        Err(e) => {
            tracing::warn!("refusing a connection: no peer credentials: {e}");
            return None;
        }
    }
    let setup = |s: &UnixStream| -> std::io::Result<UnixStream> {
        s.set_nonblocking(false)?;
        let w = s.try_clone()?;
        w.set_write_timeout(Some(Duration::from_secs(2)))?;
        Ok(w)
    };
    let mut writer = match setup(&s) {
        Ok(w) => w,
        Err(e) => {
            tracing::warn!("setting up an sdid connection: {e}");
            return None;
        }
    };
    if current.is_some_and(|f| !f.done.load(Ordering::Acquire)) {
        let _ = link::write(
            &mut writer,
            &Message::Refused("another sdid feeds this camera".into()),
        );
        return None;
    }
    let writer = Arc::new(Mutex::new(writer));
    let done = Arc::new(AtomicBool::new(false));
    let greeted = Arc::new(AtomicBool::new(false));
    let (n, w, d, q) = (nodes.clone(), writer.clone(), done.clone(), quit.clone());
    let g = greeted.clone();
    let reader = std::thread::Builder::new()
        .name("sdi-camera-feed".into())
        .spawn(move || {
            match take_frames(s, &n, &w, &g, &q) {
                Ok(()) => {}
                Err(LinkError::Io(e)) if e.kind() == std::io::ErrorKind::UnexpectedEof => {}
                Err(e) => tracing::warn!("sdid's feed ended: {e}"),
            }
            d.store(true, Ordering::Release);
        });
    match reader {
        Ok(reader) => Some(Feed {
            writer,
            greeted,
            done,
            reader,
            reported: None,
            reported_at: Instant::now(),
        }),
        Err(e) => {
            tracing::warn!("starting the feed thread: {e}");
            None
        }
    }
}

/// Reads one sdid's messages into the nodes until it goes away or quits.
fn take_frames(
    mut s: UnixStream,
    nodes: &Nodes,
    writer: &Mutex<UnixStream>,
    greeted: &AtomicBool,
    quit: &AtomicBool,
) -> Result<(), LinkError> {
    let reply = |m: Message| {
        let mut w = writer.lock().unwrap_or_else(|e| e.into_inner());
        link::write(&mut *w, &m)
    };
    match link::read(&mut s)? {
        Message::Hello(spec) if nodes.spec().same_nodes(&spec) => {
            nodes.set_mode(spec.mode);
            reply(Message::Ready)?;
            greeted.store(true, Ordering::Release);
            tracing::info!(mode = spec.mode.name(), "sdid connected");
        }
        Message::Hello(spec) => {
            // New sizes or rate: this process ends, and sdid starts a new one.
            reply(Message::Refused(format!(
                "the camera publishes {}, not {spec}: restarting it",
                nodes.spec()
            )))?;
            quit.store(true, Ordering::Release);
            return Ok(());
        }
        m => return Err(LinkError::Bad(format!("expected Hello, got {m:?}"))),
    }
    let spec = nodes.spec();
    loop {
        match link::read(&mut s)? {
            Message::Frame {
                port,
                wire,
                timestamp_us,
                len,
            } => {
                let (w, h) = match port {
                    Port::View => (spec.view_width, spec.view_height),
                    Port::Data => (spec.data_width, spec.data_height),
                };
                let fits = matches!(
                    (port, wire),
                    (Port::Data, Wire::Y16) | (Port::View, Wire::Yuyv | Wire::Rgb)
                );
                if !fits || len != w as usize * h as usize * wire.bytes_per_pixel() {
                    return Err(LinkError::Bad(format!(
                        "a {len}-byte {} frame for the {port:?} node of {w}x{h}",
                        wire.name()
                    )));
                }
                let taken = nodes.offer(port, wire, timestamp_us, |bytes| {
                    link::read_payload(&mut s, len, bytes)
                })?;
                if !taken {
                    link::skip_payload(&mut s, len)?;
                }
            }
            Message::NoSignal { timestamp_us } => nodes.no_signal(timestamp_us),
            Message::Mode(mode) => nodes.set_mode(mode),
            Message::Quit => {
                quit.store(true, Ordering::Release);
                return Ok(());
            }
            m => return Err(LinkError::Bad(format!("unexpected {m:?}"))),
        }
    }
}
