//! Boards plugged in after start, while sdid serves boards by serial
//! (boards were attached at start, no `[board] serial`): each new serial
//! becomes a camera of its own at the next path, its section applied and
//! its outputs named by serial, while the cameras already served stream
//! on. The bus is looked at every [`POLL`]: descriptors only, serials read
//! only when the set of boards changed.

use std::sync::Arc;
use std::time::Duration;

use sdi_config::{BackendKind, Config, MAX_CAMERAS};
use tokio::sync::{Mutex, Notify};

use super::camera::{serve_camera, Served};
use super::StartOptions;
use crate::backend::board;
use crate::camera_plan;

/// How often the bus is looked at for a new board.
const POLL: Duration = Duration::from_secs(1);

/// The serials of the boards attached, when the configuration may serve
/// every one (the board or auto backend, no `[board] serial`).
pub(super) fn attached_boards(c: &Config) -> Vec<String> {
    if !camera_plan::serves_boards_by_serial(c) {
        return Vec::new();
    }
    board::attached_serials()
        .map_err(|e| tracing::debug!("listing the boards: {e}"))
        .unwrap_or_default()
}

/// Serves each board that arrives until the task is aborted at shutdown.
pub(super) async fn watch(
    conn: zbus::Connection,
    options: StartOptions,
    served: Arc<Mutex<Served>>,
    exits: Arc<Notify>,
) {
    // Empty at first: the first look reads the serials, so a board that
    // arrived while the others were opened is not missed.
    let mut boards = Vec::new();
    // Serials that could not be served, kept until they leave the bus (a
    // board that fails to open is not opened again every poll).
    let mut failed: Vec<String> = Vec::new();
    loop {
        tokio::time::sleep(POLL).await;
        let now = addresses().await;
        if now == boards {
            continue;
        }
        boards = now;
        let attached = match tokio::task::spawn_blocking(board::attached_serials).await {
            Ok(Ok(serials)) => serials,
            _ => continue,
        };
        failed.retain(|s| attached.contains(s));
        let mut served = served.lock().await;
        let mut known = served.serials();
        known.extend(failed.iter().cloned());
        for serial in camera_plan::new_boards(&known, &attached) {
            let count = served.cameras.len() + 1;
            if count > MAX_CAMERAS as usize {
                tracing::warn!("board {serial} arrived: sdid serves {MAX_CAMERAS} cameras at most");
                failed.push(serial);
                continue;
            }
            let mut plan = camera_plan::board_plan(&options.config, &serial, count);
            plan.config.backend = BackendKind::Opt8241;
            match serve_camera(&conn, &options, plan, &mut served, &exits).await {
                Ok(screen) => tracing::info!("board {serial} arrived:\n{screen}"),
                Err(e) => {
                    tracing::warn!("board {serial} arrived but cannot be served: {e}");
                    failed.push(serial);
                }
            }
        }
    }
}

/// The bus positions of the boards attached (descriptors only: cheap).
async fn addresses() -> Vec<(u8, u8)> {
    tokio::task::spawn_blocking(|| board::attached_addresses().unwrap_or_default())
        .await
        .unwrap_or_default()
}
