//! `sdictl view`: a live viewer and control panel for the running sdid in
//! the browser, served on 127.0.0.1 at a random port behind a random token
//! (`security`) that reaches the browser through a private file
//! (`redirect`), with bounded connections (`connections`), fed with sdid's
//! frames over D-Bus (`frames`), talking to sdid with the user's rights
//! over a connection made again when lost (`bus`, `controls`), with the
//! page's statistics in Rust (`analysis`) and the page embedded in the
//! binary (`server`).

mod analysis;
mod bus;
mod cameras;
mod connections;
mod controls;
mod frames;
mod redirect;
mod security;
mod server;

use std::net::{Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;

use clap::Args;
use sdi_api::Camera1Proxy;
use tokio::sync::{watch, Mutex};

use crate::exit::CliError;
use crate::stdout::outln;
use controls::Controls;
use security::{Guard, Token};

/// `sdictl view`'s options.
#[derive(Debug, Clone, Args)]
pub struct ViewArgs {
    /// Port on 127.0.0.1; 0 picks a free one.
    #[arg(long, default_value_t = 0)]
    pub port: u16,
    /// Do not start a browser; open the file sdictl prints yourself.
    #[arg(long)]
    pub no_open: bool,
    /// Also print the page's URL with its secret token first (anyone who
    /// sees it may drive the camera as you; never pass it on a command line).
    #[arg(long)]
    pub print_url: bool,
    /// Directory for the page's snapshots and recordings.
    #[arg(long, default_value = ".")]
    pub out_dir: PathBuf,
}

/// Serves the page until sdid's frame stream ends or Ctrl-C; `connect`
/// makes a new connection to sdid when the bus drops `camera`'s, to the
/// camera whose serial `chosen` holds (the page may choose another).
pub async fn run(
    camera: Camera1Proxy<'static>,
    connect: bus::Connect<Camera1Proxy<'static>>,
    chosen: Arc<std::sync::Mutex<Option<String>>>,
    args: ViewArgs,
) -> Result<(), CliError> {
    let limits = connections::Limits::from_env()?;
    let stream = frames::open(&camera).await?;
    let (tx, rx) = watch::channel(None);
    let (next_stream, switches) = tokio::sync::mpsc::channel(1);
    let listener =
        tokio::net::TcpListener::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, args.port)))
            .await
            .map_err(|e| CliError::Runtime(format!("listening on 127.0.0.1:{}: {e}", args.port)))?;
    let port = listener
        .local_addr()
        .map_err(|e| CliError::Runtime(e.to_string()))?
        .port();
    let guard = Guard {
        token: Token::random(),
        port,
    };
    let url = format!("http://127.0.0.1:{port}/#token={}", guard.token.as_str());
    let file = redirect::RedirectFile::write(&url)?;
    let app = server::App {
        controls: Arc::new(Controls {
            bus: bus::Link::new(camera, connect),
            camera: chosen,
            next_stream,
            out_dir: args.out_dir,
            recording: Mutex::new(None),
        }),
        frames: rx,
    };
    if args.print_url {
        outln!("{url}")?;
    }
    outln!("{}", file.path().display())?;
    if !args.no_open {
        open_browser(file.path());
    }
    let serve = connections::serve(listener, server::router(app, guard, limits), limits);
    tokio::select! {
        r = serve => r.map_err(|e| CliError::Runtime(format!("serving the page: {e}"))),
        r = follow(stream, switches, &tx) => r,
        _ = tokio::signal::ctrl_c() => Ok(()),
    }
}

/// Pumps the frames of the page's camera, and of the next one it chooses.
async fn follow(
    mut stream: tokio::net::UnixStream,
    mut switches: tokio::sync::mpsc::Receiver<frames::Switch>,
    tx: &watch::Sender<Option<Arc<frames::LiveFrame>>>,
) -> Result<(), CliError> {
    loop {
        let (next, done) = tokio::select! {
            r = frames::pump(stream, tx) => {
                return r.map_err(|e| CliError::Runtime(e.to_string()));
            }
            Some(switch) = switches.recv() => switch,
        };
        // The old stream is dropped (sdid sees its reader go), and its
        // last frame with it.
        stream = next;
        tx.send_replace(None);
        let _ = done.send(());
    }
}

/// Starts the desktop's browser on the redirect file when there is a
/// display; its path is printed either way.
fn open_browser(file: &std::path::Path) {
    let has_display = ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()));
    if !has_display {
        return;
    }
    if let Err(e) = std::process::Command::new("xdg-open")
        .arg(file)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
    {
        eprintln!("xdg-open: {e}; open the file above in a browser");
    }
}
