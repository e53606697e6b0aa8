//! `sdictl view`: a live viewer and control panel for the running sdid in
//! the browser, served on 127.0.0.1 at a random port behind a random token
//! (`security`), fed with sdid's frames over D-Bus (`frames`), talking to
//! sdid with the user's rights (`controls`), with the page's statistics in
//! Rust (`analysis`) and the page embedded in the binary (`server`).

mod analysis;
mod controls;
mod frames;
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
    /// Print the URL only, do not start a browser.
    #[arg(long)]
    pub no_open: bool,
    /// Directory for the page's snapshots and recordings.
    #[arg(long, default_value = ".")]
    pub out_dir: PathBuf,
}

/// Serves the page until sdid's frame stream ends or Ctrl-C.
pub async fn run(camera: Camera1Proxy<'static>, args: ViewArgs) -> Result<(), CliError> {
    let stream = frames::open(&camera).await?;
    let (tx, rx) = watch::channel(None);
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
    let url = format!("http://127.0.0.1:{port}/?token={}", guard.token.as_str());
    let app = server::App {
        controls: Arc::new(Controls {
            camera,
            out_dir: args.out_dir,
            recording: Mutex::new(None),
        }),
        frames: rx,
    };
    outln!("{url}")?;
    if !args.no_open {
        open_browser(&url);
    }
    let serve = axum::serve(listener, server::router(app, guard));
    tokio::select! {
        r = serve => r.map_err(|e| CliError::Runtime(format!("serving the page: {e}"))),
        r = frames::pump(stream, tx) => r.map_err(|e| CliError::Runtime(e.to_string())),
        _ = tokio::signal::ctrl_c() => Ok(()),
    }
}

/// Starts the desktop's browser on `url` when there is a display; the URL
/// is printed either way.
fn open_browser(url: &str) {
    let has_display = ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()));
    if !has_display {
        return;
    }
    if let Err(e) = std::process::Command::new("xdg-open")
        .arg(url)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
    {
        eprintln!("xdg-open: {e}; open the URL above");
    }
}
