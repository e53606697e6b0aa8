//! The backend the validated configuration asks for (`auto`: the board when
//! one is attached, else the simulator), with `[lights]` driven by the mode.

use std::sync::Arc;

use sdi_config::{BackendKind, Config, SensorSpecError};
use sdi_core::mode::ModeId;
use sdi_core::sensor::ParamError;
use sdi_opt8241::Roi;
use tokio::sync::Notify;

use super::board::{self as board_backend, BoardBackend, OnUnplug};
use super::opt8241::BoardSelector;
use super::replay::ReplayBackend;
use super::sim::SimBackend;
use super::status::StatusHandle;
use super::{Backend, BackendError};
use crate::light::{driven, select as light_select};

/// What the board backend adds: live status and the on_unplug = "exit" signal.
#[derive(Default)]
pub struct BoardExtras {
    pub status: Option<StatusHandle>,
    pub exit: Option<Arc<Notify>>,
}

/// Why the configured backend could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error("{0}")]
    Board(#[source] BackendError),
    #[error("sensor {0}")]
    Sensor(#[source] SensorSpecError),
    #[error("{0}")]
    Modulation(#[source] ParamError),
    #[error("{0}")]
    Simulator(#[source] BackendError),
    #[error("backend replay needs a recording: --replay FILE")]
    NoRecording,
    #[error("{0}")]
    Replay(#[source] BackendError),
    #[error("[lights]: {0}")]
    Lights(#[source] light_select::SelectError),
}

/// A backend and what the board adds to it.
type Opened = (Box<dyn Backend>, BoardExtras);

/// Opens the backend of `c`, wrapped so `[lights]` follow the mode.
pub fn open(c: &Config, mode: ModeId) -> Result<Opened, OpenError> {
    let (backend, extras) = build(c, mode)?;
    Ok((with_lights(c, backend)?, extras))
}

fn open_board(c: &Config, mode: ModeId) -> Result<Opened, OpenError> {
    let on_unplug = c.board.on_unplug;
    let roi = c.board.roi.map(|[x, y, width, height]| Roi {
        x,
        y,
        width,
        height,
    });
    let mut b = BoardBackend::open(board_backend::BoardBackendConfig {
        selector: BoardSelector {
            serial: c.board.serial.clone(),
            ..BoardSelector::default()
        },
        board: board_backend::board_config(roi, c.frame_rate_hz, c.exposure_us, c.modulation_hz),
        on_unplug,
        seed: c.seed,
        mode,
        hotplug_events: true,
    })
    .map_err(OpenError::Board)?;
    let extras = BoardExtras {
        status: Some(b.status()),
        exit: (on_unplug == OnUnplug::Exit).then(|| b.exit_notify()),
    };
    Ok((Box::new(b), extras))
}

fn build(c: &Config, mode: ModeId) -> Result<Opened, OpenError> {
    match c.backend {
        BackendKind::Opt8241 => open_board(c, mode),
        BackendKind::Auto => open_auto(c, mode),
        BackendKind::Sim => open_sim(c, mode),
        BackendKind::Replay => open_replay(c),
    }
}

/// The board when one is attached and usable, else the simulator; the log
/// says which and why.
fn open_auto(c: &Config, mode: ModeId) -> Result<Opened, OpenError> {
    let mut sim = c.clone();
    sim.backend = BackendKind::Sim;
    match board_backend::board_attached() {
        Ok(true) => match open_board(c, mode) {
            Ok(b) => {
                tracing::info!("backend auto: an OPT8241-CDK is attached; using it");
                Ok(b)
            }
            Err(e) => {
                tracing::warn!("backend auto: a board is attached but cannot be used ({e}); using the simulator");
                build(&sim, mode)
            }
        },
        Ok(false) => {
            tracing::info!("backend auto: no OPT8241-CDK (USB IDs of udev/board-ids) attached; using the simulator");
            build(&sim, mode)
        }
        Err(e) => {
            tracing::info!(
                "backend auto: cannot look for the board (libusb: {e}); using the simulator"
            );
            build(&sim, mode)
        }
    }
}

/// The simulator of the configured sensor, with the configured overrides.
fn open_sim(c: &Config, mode: ModeId) -> Result<Opened, OpenError> {
    let desc = c.sensor.load().map_err(OpenError::Sensor)?;
    if let Some(hz) = c.modulation_hz {
        desc.check_modulation_hz(hz)
            .map_err(OpenError::Modulation)?;
    }
    if desc.dark_current_electrons_per_us > 0.0 {
        tracing::warn!(
            "sensor '{}': dark current is not simulated by sdid (sdictl sim adds it)",
            c.sensor
        );
    }
    let mut p = desc.params();
    p.exposure_us = c.exposure_us.unwrap_or(p.exposure_us);
    p.frame_rate_hz = c.frame_rate_hz.unwrap_or(p.frame_rate_hz);
    p.modulation_hz = c.modulation_hz.unwrap_or(p.modulation_hz);
    let sim = SimBackend::new(p, mode, c.seed, c.scene.map(|s| s.spec()))
        .map_err(OpenError::Simulator)?;
    Ok((Box::new(sim), BoardExtras::default()))
}

/// The recording `[replay]` names, at the configured frame rate if any.
fn open_replay(c: &Config) -> Result<Opened, OpenError> {
    let path = c.replay.path.as_ref().ok_or(OpenError::NoRecording)?;
    let mut b = ReplayBackend::open(path, c.replay.looping).map_err(OpenError::Replay)?;
    if let Some(fps) = c.frame_rate_hz {
        let mut s = b.settings();
        s.frame_rate_hz = fps;
        b.configure(&s).map_err(OpenError::Replay)?;
    }
    Ok((Box::new(b), BoardExtras::default()))
}

/// Wraps the backend so `[lights]` follow the mode.
fn with_lights(c: &Config, backend: Box<dyn Backend>) -> Result<Box<dyn Backend>, OpenError> {
    match light_select::open(&c.lights).map_err(OpenError::Lights)? {
        Some(lights) => Ok(Box::new(driven::LitBackend::new(
            backend,
            lights,
            driven::LightSwitch::default(),
        ))),
        None => Ok(backend),
    }
}
