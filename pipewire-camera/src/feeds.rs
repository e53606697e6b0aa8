//! `sdi-pipewire-camera --system-feed [DIR]`: the cameras of a user's
//! session fed by the system sdid, one per feed socket it offers in DIR
//! (`/run/sdi` by default; `camera-feed.sock` for a lone camera,
//! `camera-feed-SERIAL.sock` for each of several). Each is served by a
//! thread of its own ([`server::run_fed`]: its own lock, PipeWire
//! connection and nodes), and served again while its socket is there
//! after it ended (other sizes, asked to quit).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::thread::JoinHandle;
use std::time::Duration;

use sdi_camera_link::system_feed_camera;

use crate::server::{self, ServeError};

/// Between looks for new feed sockets.
const LOOK: Duration = Duration::from_secs(2);

/// Entry point: serves every feed socket found in `dir`, until PipeWire is
/// lost (the unit starts the program again).
pub fn main(dir: &Path) -> ExitCode {
    tracing::info!(dir = %dir.display(), "PipeWire cameras waiting for the system sdid's feeds");
    let mut serving: HashMap<PathBuf, JoinHandle<Result<(), ServeError>>> = HashMap::new();
    loop {
        let ended: Vec<PathBuf> = serving
            .iter()
            .filter(|(_, t)| t.is_finished())
            .map(|(p, _)| p.clone())
            .collect();
        for path in ended {
            let Some(thread) = serving.remove(&path) else {
                continue;
            };
            match thread.join() {
                Ok(Ok(())) => tracing::info!(feed = %path.display(), "a PipeWire camera ended"),
                Ok(Err(e @ ServeError::ConnectionLost)) => return server::fail(&e),
                Ok(Err(e)) => tracing::warn!(feed = %path.display(), "PipeWire camera: {e}"),
                Err(_) => {
                    tracing::warn!(feed = %path.display(), "a PipeWire camera's thread panicked")
                }
            }
        }
        for path in feed_sockets(dir) {
            if serving.contains_key(&path) {
                continue;
            }
            let p = path.clone();
            match std::thread::Builder::new()
                .name("sdi-camera-fed".into())
                .spawn(move || server::run_fed(&p))
            {
                Ok(t) => {
                    serving.insert(path, t);
                }
                Err(e) => tracing::warn!(feed = %path.display(), "starting a camera thread: {e}"),
            }
        }
        std::thread::sleep(LOOK);
    }
}

/// The feed sockets in `dir`, by name ([`system_feed_camera`]); none while
/// it is missing (no system sdid).
fn feed_sockets(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .filter(|e| {
            e.file_name()
                .to_str()
                .and_then(system_feed_camera)
                .is_some()
        })
        .map(|e| e.path())
        .collect();
    found.sort();
    found
}
