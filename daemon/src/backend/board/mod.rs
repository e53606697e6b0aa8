//! The TI OPT8241-CDK as a daemon [`Backend`]: capture settings mapped onto
//! the board's registers, unplug and replug, and what stands in meanwhile
//! (`[board] on_unplug`).
//!
//! Frames are the decoded raw-quad difference (quad 0 = LS1 - LS2, eq.
//! pixeleff); the dark frame is subtracted by the mode pipeline, as for the
//! other backends. While the board is gone, `capture` reports
//! [`BackendError::Unavailable`] and opens the board again as soon as a
//! libusb hotplug event says it is back ([`HotplugWatch`]), and in any case
//! on a bus scan every [`RECONNECT_INTERVAL`] (every
//! [`HOTPLUG_FALLBACK_INTERVAL`] once hotplug events have been seen): a
//! fresh libusb scan works without udev, where libusb delivers no events.
//! Opening runs on a thread of its own, so a device that takes seconds to
//! fail (never answering, never leaving UVC mode) never holds the frame
//! loop; losses, returns and failures are logged once per cause.

use std::sync::Arc;
use std::time::{Duration, Instant};

use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::sensor::SensorParams;
use sdi_core::Frame;
use sdi_opt8241::health;
use sdi_opt8241::BoardConfig;

use super::opt8241::device::Connection;
use super::opt8241::hotplug::HotplugWatch;
use super::opt8241::usb::UsbError;
use super::opt8241::{BoardError, BoardSelector, Opt8241};
use super::sim::SimBackend;
use super::status::{DeviceStatus, StatusHandle};
use super::{Backend, BackendError, BackendName, CaptureSettings, Limits};
use crate::cause_log::{repeats, CauseLog};
use sdi_core::quad_phase::{PhaseAxis, PhaseSums};

mod opening;
mod settings;

use opening::Opening;
use settings::actual_sensor;
pub use settings::{board_config, board_limits, exposure_us_of, integration_percent_for};

/// How often a missing board is looked for by a bus scan.
pub const RECONNECT_INTERVAL: Duration = Duration::from_millis(500);
/// The bus-scan interval once libusb has delivered hotplug events: the
/// events do the work, the scan is a safety net.
pub const HOTPLUG_FALLBACK_INTERVAL: Duration = Duration::from_secs(5);

/// What brought the board back, counted over the backend's life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReconnectCounts {
    /// Reconnections started by a libusb hotplug arrival.
    pub by_hotplug: u64,
    /// Reconnections started by the periodic bus scan.
    pub by_poll: u64,
}

/// What sdid does while the board is unplugged (`[board] on_unplug`).
pub use sdi_config::OnUnplug;

/// Settings of the board backend.
#[derive(Debug, Clone)]
pub struct BoardBackendConfig {
    pub selector: BoardSelector,
    pub board: BoardConfig,
    pub on_unplug: OnUnplug,
    /// Seed of the stand-in simulator.
    pub seed: u64,
    pub mode: ModeId,
    /// Listen for libusb hotplug events (sdid does). Off, only the bus scan
    /// finds a replugged board, as with a libusb that delivers no events.
    pub hotplug_events: bool,
}

pub struct BoardBackend {
    board: Opt8241,
    sensor: SensorParams,
    on_unplug: OnUnplug,
    mode: ModeId,
    seed: u64,
    stand_in: Option<SimBackend>,
    status: StatusHandle,
    /// Set when `on_unplug = "exit"` and the board went away.
    exit: Option<Arc<tokio::sync::Notify>>,
    next_attempt: Instant,
    unplugged_at: Option<Instant>,
    /// None when libusb has no hotplug support (or registering failed).
    hotplug: Option<HotplugWatch>,
    /// A hotplug arrival not yet acted on.
    arrival_pending: bool,
    reconnects: ReconnectCounts,
    /// When temperatures and op_overflow were last read.
    last_health_poll: Instant,
    /// The board being opened again, off the frame loop's thread.
    opening: Option<Opening>,
    /// Losses, returns and failed reconnections, logged once per cause
    /// ([`CauseLog`]): a device on the board's IDs decides how often they
    /// happen (a re-enumeration storm, a stall on every request).
    log: CauseLog,
}

fn clamp_text(board: &Opt8241) -> String {
    board
        .init_report()
        .clamps
        .iter()
        .map(|c| format!("{} {} -> {} ({})", c.field, c.requested, c.actual, c.reason))
        .collect::<Vec<_>>()
        .join("; ")
}

fn board_err(e: BoardError) -> BackendError {
    match e {
        BoardError::DeviceUnavailable => BackendError::Unavailable(e.to_string()),
        BoardError::Usb(u) => BackendError::Unavailable(u.to_string()),
        BoardError::Config(c) => BackendError::OutOfRange(c.to_string()),
        BoardError::NotYet => BackendError::NotYet,
        other => BackendError::Failed(other.to_string()),
    }
}

impl BoardBackend {
    /// Opens and configures the board; fails when it is not attached.
    pub fn open(c: BoardBackendConfig) -> Result<Self, BackendError> {
        let board = Opt8241::open(c.selector, c.board.clone()).map_err(board_err)?;
        let device = describe(&board);
        let clamps = clamp_text(&board);
        if !clamps.is_empty() {
            tracing::warn!("the board clamped settings (laser safety): {clamps}");
        }
        tracing::info!(%device, "OPT8241-CDK configured and streaming");
        let watch = if c.hotplug_events {
            HotplugWatch::start()
        } else {
            Ok(None)
        };
        let hotplug = match watch {
            Ok(Some(h)) => {
                tracing::info!(
                    "unplug/replug: libusb hotplug events, and a bus scan every {:?} \
                     ({:?} once events arrive; a libusb built on udev delivers none without udevd)",
                    RECONNECT_INTERVAL,
                    HOTPLUG_FALLBACK_INTERVAL
                );
                Some(h)
            }
            Ok(None) => {
                tracing::info!(
                    "unplug/replug: no libusb hotplug events; a bus scan every {:?}",
                    RECONNECT_INTERVAL
                );
                None
            }
            Err(e) => {
                tracing::warn!(
                    "unplug/replug: libusb hotplug registration failed ({e}); a bus scan every {:?}",
                    RECONNECT_INTERVAL
                );
                None
            }
        };
        Ok(Self {
            sensor: actual_sensor(&board),
            board,
            on_unplug: c.on_unplug,
            mode: c.mode,
            seed: c.seed,
            stand_in: None,
            status: StatusHandle::new(DeviceStatus {
                backend: "opt8241".into(),
                device,
                available: true,
                detail: if clamps.is_empty() {
                    String::new()
                } else {
                    format!("clamped: {clamps}")
                },
                health: None,
            }),
            // the first frame polls at once
            last_health_poll: Instant::now()
                .checked_sub(health::POLL_INTERVAL)
                .unwrap_or_else(Instant::now),
            exit: None,
            next_attempt: Instant::now(),
            unplugged_at: None,
            hotplug,
            arrival_pending: false,
            reconnects: ReconnectCounts::default(),
            opening: None,
            log: CauseLog::default(),
        })
    }

    /// Board hotplug events libusb delivered so far; `None` without a
    /// hotplug registration.
    pub fn hotplug_events(&self) -> Option<u64> {
        self.hotplug.as_ref().map(HotplugWatch::events_seen)
    }

    /// Successful reconnections, by what started them.
    pub fn reconnects(&self) -> ReconnectCounts {
        self.reconnects
    }

    /// The bus-scan interval now: slow once hotplug events are known to
    /// arrive.
    fn poll_interval(&self) -> Duration {
        match self.hotplug_events() {
            Some(n) if n > 0 => HOTPLUG_FALLBACK_INTERVAL,
            _ => RECONNECT_INTERVAL,
        }
    }

    fn health_due(&self) -> bool {
        self.last_health_poll.elapsed() >= health::POLL_INTERVAL
    }

    /// Reads temperatures and op_overflow into the status, logs changes;
    /// true when the board overflowed since the last poll.
    fn poll_health(&mut self) -> bool {
        self.last_health_poll = Instant::now();
        let Some(bus) = self.board.registers() else {
            return false;
        };
        let status = match health::poll(bus) {
            Ok(s) => s,
            Err(e) => {
                tracing::debug!("board status not read: {e}");
                return false;
            }
        };
        let (now, lines) = health::update(self.status.get().health, &status);
        for line in &lines {
            tracing::warn!("{line}");
        }
        self.status.update(|s| s.health = Some(now));
        status.output_overflow
    }

    /// Live state for D-Bus (Backend, Device, Stats).
    pub fn status(&self) -> StatusHandle {
        self.status.clone()
    }

    /// Notified once when the board goes away and `on_unplug = "exit"`.
    pub fn exit_notify(&mut self) -> Arc<tokio::sync::Notify> {
        self.exit
            .get_or_insert_with(|| Arc::new(tokio::sync::Notify::new()))
            .clone()
    }

    fn lost(&mut self, why: &str) {
        if self.unplugged_at.is_none() {
            if let Some(quiet) = self.log.admit("lost") {
                tracing::warn!(
                    "board lost: {why}; on_unplug = {:?}{}",
                    self.on_unplug,
                    repeats(quiet)
                );
            }
            self.unplugged_at = Some(Instant::now());
        }
        match self.on_unplug {
            OnUnplug::NoSignal | OnUnplug::Exit => self.status.update(|s| {
                s.available = false;
                s.detail = format!("DeviceUnavailable: {why}");
            }),
            OnUnplug::Simulator => {
                if self.stand_in.is_none() {
                    self.seed = self.seed.wrapping_add(1);
                    match SimBackend::new(self.sensor.clone(), self.mode, self.seed, None) {
                        Ok(sim) => {
                            tracing::info!("the simulator stands in until the board is back");
                            self.status.update(|s| {
                                s.backend = "sim".into();
                                s.device = sim.device();
                                s.available = true;
                                s.detail = format!("simulator standing in: {why}");
                            });
                            self.stand_in = Some(sim);
                        }
                        Err(e) => tracing::error!("cannot start the stand-in simulator: {e}"),
                    }
                }
            }
        }
        if self.on_unplug == OnUnplug::Exit {
            if let Some(n) = &self.exit {
                n.notify_one();
            }
        }
    }

    /// Starts opening the board (on a thread of its own) when a hotplug
    /// arrival came or a scan is due, and takes the outcome once it is
    /// there; true when the board is back.
    fn try_reconnect(&mut self) -> bool {
        if let Some(h) = &self.hotplug {
            self.arrival_pending |= h.drain().arrived;
        }
        if let Some(opening) = self.opening.as_mut() {
            let Some(outcome) = opening.poll() else {
                return false;
            };
            let by_hotplug = opening.by_hotplug;
            self.opening = None;
            return self.opened(outcome, by_hotplug);
        }
        let by_hotplug = std::mem::take(&mut self.arrival_pending);
        if !by_hotplug && Instant::now() < self.next_attempt {
            return false;
        }
        self.opening = Some(Opening {
            rx: self.board.reconnect_in_background(),
            by_hotplug,
            outcome: None,
        });
        false
    }

    /// Acts on the outcome of opening the board; true when it is back.
    fn opened(&mut self, outcome: Result<Connection, BoardError>, by_hotplug: bool) -> bool {
        // After an arrival the device may not be ready at once: scan again
        // soon rather than after the slow fallback interval.
        self.next_attempt = Instant::now()
            + if by_hotplug {
                RECONNECT_INTERVAL
            } else {
                self.poll_interval()
            };
        match outcome {
            Ok(connection) => {
                self.board.resume(connection);
                let waited = self.unplugged_at.take().map(|t| t.elapsed());
                let device = describe(&self.board);
                let trigger = if by_hotplug {
                    self.reconnects.by_hotplug += 1;
                    "libusb hotplug event"
                } else {
                    self.reconnects.by_poll += 1;
                    "bus scan"
                };
                if let Some(quiet) = self.log.admit("back") {
                    tracing::info!(
                        %device,
                        ?waited,
                        trigger,
                        "board is back; streaming again{}",
                        repeats(quiet)
                    );
                }
                self.stand_in = None;
                self.status.update(|s| {
                    s.backend = "opt8241".into();
                    s.device = device;
                    s.available = true;
                    s.detail = String::new();
                });
                true
            }
            Err(e) => {
                // A device on the board's IDs that cannot be used is worth one
                // line per cause; no device at all, or one that left while
                // being opened, is the normal wait.
                let quiet = match e {
                    BoardError::Usb(UsbError::NotFound { .. } | UsbError::Disconnected)
                    | BoardError::DeviceUnavailable => None,
                    _ => self.log.admit(e.cause()),
                };
                match quiet {
                    Some(quiet) => tracing::warn!(
                        "a device on the board's USB IDs cannot be used: {e}{}",
                        repeats(quiet)
                    ),
                    None => tracing::debug!("board still missing: {e}"),
                }
                false
            }
        }
    }
}

fn describe(board: &Opt8241) -> String {
    match board.serial() {
        Some(s) => format!("TI OPT8241-CDK (USB 0451:9105, serial {s})"),
        None => "TI OPT8241-CDK (USB 0451:9105)".into(),
    }
}

impl Backend for BoardBackend {
    fn kind(&self) -> BackendName {
        BackendName::Opt8241
    }

    fn device(&self) -> String {
        self.status.get().device
    }

    fn serial(&self) -> Option<String> {
        self.board.serial().map(str::to_owned)
    }

    fn sensor(&self) -> &SensorParams {
        &self.sensor
    }

    fn limits(&self) -> Limits {
        board_limits(self.board.config())
    }

    fn settings(&self) -> CaptureSettings {
        CaptureSettings {
            exposure_us: self.sensor.exposure_us,
            frame_rate_hz: self.sensor.frame_rate_hz,
            modulation_hz: self.sensor.modulation_hz,
        }
    }

    /// Writes the settings to the board, reads them back and reports clamps
    /// (laser safety: the firmware's, never bypassed).
    fn configure(&mut self, s: &CaptureSettings) -> Result<(), BackendError> {
        if !self.board.is_connected() {
            return Err(BackendError::Unavailable(
                "the board is unplugged; settings can change when it is back".into(),
            ));
        }
        let mut c = self.board.config().clone();
        c.frame_rate_hz = s.frame_rate_hz;
        c.modulation_hz = s.modulation_hz;
        c.integration_percent = integration_percent_for(s.exposure_us, &c);
        if let Err(e) = c.validate() {
            return Err(BackendError::OutOfRange(e.to_string()));
        }
        if let Err(e) = self.board.reconfigure(c) {
            let e = board_err(e);
            if matches!(e, BackendError::Unavailable(_)) {
                self.lost(&e.to_string());
            }
            return Err(e);
        }
        self.sensor = actual_sensor(&self.board);
        let clamps = clamp_text(&self.board);
        if !clamps.is_empty() {
            tracing::warn!("the board clamped settings (laser safety): {clamps}");
        }
        self.status.update(|st| {
            st.detail = if clamps.is_empty() {
                String::new()
            } else {
                format!("clamped: {clamps}")
            }
        });
        Ok(())
    }

    fn set_mode(&mut self, mode: ModeId) {
        self.mode = mode;
        if let Some(sim) = self.stand_in.as_mut() {
            sim.set_mode(mode);
        }
    }

    /// The stand-in simulator is paced like any simulator; the board has its own clock.
    fn paced_rate_hz(&self) -> Option<f64> {
        match &self.stand_in {
            Some(sim) if !self.board.is_connected() => sim.paced_rate_hz(),
            _ => None,
        }
    }

    /// Sums (I, Q) of the board's frames only: a stand-in's are not counted.
    fn measure_phase(&mut self, on: bool) -> Result<(), BackendError> {
        self.board.measure_phase(on);
        Ok(())
    }

    fn take_phase_sums(&mut self) -> Option<PhaseSums> {
        self.board.take_phase_sums()
    }

    /// The axis stays through unplug and replug: it belongs to the board
    /// and its LED path, which a replug does not change.
    fn set_phase_axis(&mut self, axis: Option<PhaseAxis>) -> Result<(), BackendError> {
        self.board.set_phase_axis(axis);
        Ok(())
    }

    fn capture(
        &mut self,
        illumination: &Illumination,
        frame: &mut Frame,
    ) -> Result<(), BackendError> {
        if !self.board.is_connected() && !self.try_reconnect() {
            if let Some(sim) = self.stand_in.as_mut() {
                return sim.capture(illumination, frame);
            }
            // Wake early when the opening ends or on a hotplug arrival.
            match (self.opening.as_mut(), &self.hotplug) {
                (Some(opening), _) => opening.wait(RECONNECT_INTERVAL / 5),
                (None, Some(h)) => self.arrival_pending |= h.wait_arrival(RECONNECT_INTERVAL / 5),
                (None, None) => std::thread::sleep(RECONNECT_INTERVAL / 5),
            }
            return Err(BackendError::Unavailable(
                "OPT8241-CDK unplugged; waiting for it".into(),
            ));
        }
        match self.board.next_frame(illumination, frame) {
            Ok(()) if self.health_due() && self.poll_health() => {
                // The frame the overflow was seen with is not trusted.
                self.board
                    .next_frame(illumination, frame)
                    .map_err(board_err)
            }
            Ok(()) => Ok(()),
            // The wait for the frame goes on at the next call.
            Err(BoardError::NotYet) => Err(BackendError::NotYet),
            Err(BoardError::DeviceUnavailable) => {
                // Events from before the loss (e.g. the re-enumeration of a
                // UVC -> bulk switch) say nothing about the board coming back.
                if let Some(h) = &self.hotplug {
                    h.drain();
                }
                self.lost("unplugged");
                self.next_attempt = Instant::now() + self.poll_interval();
                Err(BackendError::Unavailable("OPT8241-CDK unplugged".into()))
            }
            Err(e) => {
                let stats = self.board.stats();
                tracing::debug!(?stats, "board: {e}");
                if let Some(quiet) = self.log.admit(e.cause()) {
                    tracing::warn!("board: {e}{}", repeats(quiet));
                }
                Err(board_err(e))
            }
        }
    }
}

/// Is a board attached (any ID of `udev/board-ids`)? `Err` says why libusb
/// could not look.
pub fn board_attached() -> Result<bool, rusb::Error> {
    let ctx = rusb::Context::new()?;
    Ok(super::opt8241::usb::board_present(&ctx))
}

/// Where the attached boards are on the bus (bus, address), sorted.
pub fn attached_addresses() -> Result<Vec<(u8, u8)>, rusb::Error> {
    let ctx = rusb::Context::new()?;
    Ok(super::opt8241::usb::board_addresses(&ctx))
}

/// The serials of the attached boards (sorted); `Err` says why libusb
/// could not look.
pub fn attached_serials() -> Result<Vec<String>, rusb::Error> {
    let ctx = rusb::Context::new()?;
    Ok(super::opt8241::usb::board_serials(&ctx))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_unplug_names() {
        for n in OnUnplug::NAMES {
            assert!(n.parse::<OnUnplug>().is_ok());
        }
        assert!("restart".parse::<OnUnplug>().is_err());
        assert_eq!(OnUnplug::default(), OnUnplug::NoSignal);
    }
}
