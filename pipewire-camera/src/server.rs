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
use std::path::{Path, PathBuf};
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
pub(crate) enum ServeError {
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

pub(crate) fn fail(why: &ServeError) -> ExitCode {
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
    let Some(_lock) = try_lock(&dir, spec.names())? else {
        // Another camera process runs: the sdid that started this one connects to it.
        announce(link::BUSY_LINE);
        return Ok(());
    };
    let nodes = Arc::new(Nodes::open(&spec)?);
    let sock = dir.join(spec.names().socket());
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

/// This user's lock of the camera `names`, unless another camera process
/// holds it.
fn try_lock(dir: &Path, names: link::Names) -> Result<Option<Flock<std::fs::File>>, ServeError> {
    let lock_path = dir.join(names.lock());
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
    match Flock::lock(lock_file, FlockArg::LockExclusiveNonblock) {
        Ok(l) => Ok(Some(l)),
        Err((_, Errno::EWOULDBLOCK)) => Ok(None),
        Err((_, source)) => Err(ServeError::Locking {
            path: lock_path,
            source,
        }),
    }
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

/// Whether `quit` is set (logged).
fn asked_to_quit(quit: &AtomicBool) -> bool {
    let asked = quit.load(Ordering::Acquire);
    if asked {
        tracing::info!("PipeWire camera: asked to quit");
    }
    asked
}

/// Takes a feed whose sdid went away and joins its reader: whether one did.
fn reap_ended(feed: &mut Option<Feed>) -> bool {
    if !feed
        .as_ref()
        .is_some_and(|f| f.done.load(Ordering::Acquire))
    {
        return false;
    }
    if let Some(f) = feed.take() {
        let _ = f.reader.join();
    }
    true
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
        if asked_to_quit(&quit) {
            return Ok(());
        }
        if reap_ended(&mut feed) {
            away_since = Instant::now();
            tracing::info!("sdid went away: showing the no-signal card");
        }
        let state = report_or_card(&mut feed, nodes, &mut card_at);
        if feed.is_none()
            && away_since.elapsed() >= LINGER
            && state.view.is_none()
            && state.data.is_none()
        {
            tracing::info!(
                "PipeWire camera: no sdid for {} s and no reader: exiting",
                LINGER.as_secs()
            );
            return Ok(());
        }
    }
}

/// Reports the nodes' state to the greeted sdid when it changed, or shows
/// the "no signal" card while none feeds; returns the state.
fn report_or_card(feed: &mut Option<Feed>, nodes: &Nodes, card_at: &mut Instant) -> State {
    let state = nodes.state();
    match feed {
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
                *card_at = Instant::now();
                nodes.no_signal(monotonic_now_us());
            }
        }
    }
    state
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
    start_feed(s, nodes, quit, current, None)
}

/// Takes `s` as the feeding sdid (whose `hello` was read already, when
/// given), unless one already feeds.
fn start_feed(
    s: UnixStream,
    nodes: &Arc<Nodes>,
    quit: &Arc<AtomicBool>,
    current: Option<&Feed>,
    hello: Option<Spec>,
) -> Option<Feed> {
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
            match take_frames(s, hello, &n, &w, &g, &q) {
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

/// Reads one sdid's messages into the nodes until it goes away or quits;
/// its Hello first, unless `hello` holds it already.
fn take_frames(
    mut s: UnixStream,
    hello: Option<Spec>,
    nodes: &Nodes,
    writer: &Mutex<UnixStream>,
    greeted: &AtomicBool,
    quit: &AtomicBool,
) -> Result<(), LinkError> {
    let reply = |m: Message| {
        let mut w = writer.lock().unwrap_or_else(|e| e.into_inner());
        link::write(&mut *w, &m)
    };
    let first = match hello {
        Some(spec) => Message::Hello(spec),
        None => link::read(&mut s)?,
    };
    match first {
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

/// Between attempts to reach the system sdid's feed socket, and to take
/// this user's camera lock.
const REDIAL: Duration = Duration::from_secs(2);

/// Why one attempt to reach the system sdid failed.
#[derive(Debug, thiserror::Error)]
enum DialError {
    #[error("connecting: {0}")]
    Connect(#[source] std::io::Error),
    #[error("the feed socket's peer credentials: {0}")]
    PeerCredentials(#[source] Errno),
    /// Only root (the system service) may feed this user's camera.
    #[error("the feed socket is served by uid {0}, not root: refused")]
    NotRoot(u32),
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("the system sdid opened with {0}, not Hello")]
    NotHello(String),
}

/// Connects to the system sdid's feed socket at `path` and reads its Hello.
fn dial(path: &Path) -> Result<(UnixStream, Spec), DialError> {
    let s = UnixStream::connect(path).map_err(DialError::Connect)?;
    let peer = getsockopt(&s, PeerCredentials).map_err(DialError::PeerCredentials)?;
    if peer.uid() != 0 {
        return Err(DialError::NotRoot(peer.uid()));
    }
    s.set_read_timeout(Some(Duration::from_secs(5)))
        .map_err(LinkError::Io)?;
    let spec = match link::read(&mut &s)? {
        Message::Hello(spec) => spec,
        m => return Err(DialError::NotHello(format!("{m:?}"))),
    };
    s.set_read_timeout(None).map_err(LinkError::Io)?;
    Ok((s, spec))
}

/// Entry point of `sdi-pipewire-camera --system-feed [PATH]`: the camera of
/// a user's session fed by the system sdid (the user unit
/// `sdi-pipewire-camera.service`, docs/pipewire.md). It dials PATH, again
/// every [`REDIAL`] while no system sdid serves it, creates the nodes with
/// the first Hello's sizes and keeps them while that sdid restarts or goes
/// (the "no signal" card meanwhile); a Hello with other sizes ends it, and
/// its unit starts it again.
pub fn main_system_feed(path: PathBuf) -> ExitCode {
    SERVING.store(true, Ordering::Relaxed);
    match run_fed(&path) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(&e),
    }
}

/// Serves the camera whose feed socket is `path` (its name tells which:
/// [`link::system_feed_camera`]; another name, a lone camera's) until it
/// is asked to quit, needs other sizes or loses PipeWire.
pub(crate) fn run_fed(path: &Path) -> Result<(), ServeError> {
    let dir = link::runtime_dir().map_err(ServeError::RuntimeDir)?;
    let camera = path
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(link::system_feed_camera)
        .flatten();
    let names = link::Names {
        camera: camera.as_deref(),
    };
    // This camera's lock (one process per camera and user), taken once a
    // system sdid is there: a session's own sdid (no system service) keeps
    // its camera meanwhile.
    let mut lock = None;
    tracing::info!(feed = %path.display(), "PipeWire camera waiting for the system sdid");
    let quit = Arc::new(AtomicBool::new(false));
    let mut nodes: Option<Arc<Nodes>> = None;
    let mut feed: Option<Feed> = None;
    let mut card_at = Instant::now();
    let mut dial_at = Instant::now();
    let mut last_error = String::new();
    loop {
        std::thread::sleep(Duration::from_millis(u64::from(TICK_MS)));
        if nodes.as_ref().is_some_and(|n| n.broken()) {
            return Err(ServeError::ConnectionLost);
        }
        if asked_to_quit(&quit) {
            return Ok(());
        }
        if reap_ended(&mut feed) {
            tracing::info!("the system sdid went away: showing the no-signal card");
        }
        if feed.is_none() && Instant::now() >= dial_at {
            dial_at = Instant::now() + REDIAL;
            if lock.is_none() {
                lock = try_lock(&dir, names)?;
            }
            if lock.is_none() {
                if last_error != "busy" {
                    tracing::info!("another PipeWire camera runs for this user: waiting");
                    last_error = "busy".into();
                }
                continue;
            }
            match dial(path) {
                Ok((_, spec)) if camera.is_some() && spec.camera != camera => {
                    return Err(ServeError::Spec(format!(
                        "the feed {} greets camera {:?}: not this socket's",
                        path.display(),
                        spec.camera
                    )))
                }
                Ok((s, spec)) => {
                    let n = match &nodes {
                        Some(n) if n.spec().same_nodes(&spec) => n.clone(),
                        Some(n) => {
                            return Err(ServeError::Spec(format!(
                                "the system sdid now publishes {spec}, not {}: restarting",
                                n.spec()
                            )))
                        }
                        None => {
                            let n = Arc::new(Nodes::open(&spec)?);
                            nodes = Some(n.clone());
                            n
                        }
                    };
                    feed = start_feed(s, &n, &quit, None, Some(spec));
                    last_error.clear();
                }
                Err(e) => {
                    // Until it has nodes, the lock is free for the camera
                    // of a session's own sdid.
                    if nodes.is_none() {
                        lock = None;
                    }
                    // Said once, not every 2 s while no system sdid runs.
                    let e = e.to_string();
                    if e != last_error {
                        tracing::info!(feed = %path.display(), "no system sdid to feed the camera: {e}");
                        last_error = e;
                    }
                }
            }
        }
        if let Some(n) = &nodes {
            report_or_card(&mut feed, n, &mut card_at);
        }
    }
}
