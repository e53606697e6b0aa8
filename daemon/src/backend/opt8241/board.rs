//! The OPT8241-CDK backend: open, configure, stream, decode, reconnect.
//!
//! `next_frame` has the shape of the daemon's `Backend::next_frame`; on
//! unplug it returns [`BoardError::DeviceUnavailable`] and the daemon keeps
//! its output open (showing "no signal") and calls [`Opt8241::reconnect`]
//! until the board is back.

use std::time::{Duration, Instant};

use rusb::Context;
use sdi_core::modulation::Illumination;
use sdi_core::Frame;

use super::frame::{Assembled, AssemblerStats, DecodeError, FrameAssembler, QuadDecoder};
use super::init::{configure, layout_of, BoardConfig, ConfigError, InitReport};
use super::protocol::{ProtocolError, RegisterBus};
use super::usb::{open_board, BoardSelector, BulkStream, StreamEvent, UsbError, UsbTransport};

/// Transfers queued at the host controller while streaming.
pub const DEFAULT_TRANSFERS_IN_FLIGHT: usize = 4;
/// How long `next_frame` waits for a frame (the SDK waits 2 s).
pub const FRAME_WAIT: Duration = Duration::from_secs(2);
/// Read timeout of one bulk transfer (the SDK uses 200 ms).
pub const READ_TIMEOUT: Duration = Duration::from_millis(200);

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoardError {
    #[error(transparent)]
    Usb(#[from] UsbError),
    #[error(transparent)]
    Protocol(#[from] ProtocolError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Decode(#[from] DecodeError),
    /// The board was unplugged or reset; call `reconnect`.
    #[error("board unavailable (unplugged?); waiting for it to come back")]
    DeviceUnavailable,
    #[error("no frame from the board within {waited_ms} ms ({detail})")]
    NoFrame { waited_ms: u128, detail: String },
}

impl BoardError {
    fn from_protocol(e: ProtocolError) -> Self {
        if e.is_disconnect() {
            BoardError::DeviceUnavailable
        } else {
            BoardError::Protocol(e)
        }
    }
}

/// Stream counters for the daemon's Stats property.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    pub assembler: AssemblerStats,
    pub timeouts: u64,
    pub halts_cleared: u64,
    pub overflows: u64,
    pub errors: u64,
    pub reconnects: u64,
}

struct Session {
    bus: RegisterBus<UsbTransport>,
    stream: BulkStream,
    assembler: FrameAssembler,
    serial: Option<String>,
}

/// A running OPT8241-CDK.
pub struct Opt8241 {
    context: Context,
    selector: BoardSelector,
    config: BoardConfig,
    decoder: QuadDecoder,
    session: Option<Session>,
    report: InitReport,
    stats: StreamStats,
    sequence: u64,
    started: Instant,
    pub transfers_in_flight: usize,
}

fn new_context() -> Result<Context, BoardError> {
    Ok(Context::new().map_err(|e| UsbError::Usb {
        op: "initializing libusb",
        error: e.to_string(),
    })?)
}

impl Opt8241 {
    /// Finds, opens and configures the board, and starts streaming.
    pub fn open(selector: BoardSelector, config: BoardConfig) -> Result<Self, BoardError> {
        config.validate().map_err(ConfigError::from)?;
        let context = new_context()?;
        let mut board = Self {
            context,
            selector,
            decoder: QuadDecoder::new(layout_of(&config)),
            config,
            session: None,
            report: InitReport::default(),
            stats: StreamStats::default(),
            sequence: 0,
            started: Instant::now(),
            transfers_in_flight: DEFAULT_TRANSFERS_IN_FLIGHT,
        };
        board.connect()?;
        Ok(board)
    }

    fn connect(&mut self) -> Result<(), BoardError> {
        self.session = None;
        // A fresh libusb context rescans the bus: works without udev or
        // libusb hotplug support (e.g. inside minimal VMs and containers).
        self.context = new_context()?;
        let open = open_board(&self.context, &self.selector)?;
        let mut bus = RegisterBus::new(UsbTransport {
            handle: open.handle.clone(),
        });
        self.report = configure(&mut bus, &self.config).map_err(|e| match e {
            ConfigError::Protocol(p) => BoardError::from_protocol(p),
            other => BoardError::Config(other),
        })?;
        let layout = layout_of(&self.config);
        self.decoder.layout = layout;
        self.decoder.frame_number_in_first_byte = self.config.frame_numbers;
        let stream = BulkStream::start(
            open.handle,
            open.endpoint,
            layout.frame_bytes(),
            self.transfers_in_flight,
            READ_TIMEOUT,
        );
        self.session = Some(Session {
            bus,
            stream,
            assembler: FrameAssembler::new(layout.frame_bytes(), self.config.frame_numbers),
            serial: open.serial,
        });
        Ok(())
    }

    /// The configuration in use.
    pub fn config(&self) -> &BoardConfig {
        &self.config
    }

    /// Stops streaming, configures the board anew (read-back and clamps in
    /// [`Opt8241::init_report`]) and streams again. A `config` the chip
    /// cannot hold changes nothing; one the board refuses during
    /// configuration (a status flag) puts the last good one back, so the
    /// board is never left unconfigured nor retried with it; on a USB
    /// failure the board counts as unplugged and `config` is used on
    /// reconnection.
    pub fn reconfigure(&mut self, config: BoardConfig) -> Result<(), BoardError> {
        config.validate().map_err(ConfigError::from)?;
        let previous = std::mem::replace(&mut self.config, config);
        match self.connect() {
            Err(refused @ BoardError::Config(_)) => {
                self.config = previous;
                if let Err(e) = self.connect() {
                    tracing::warn!("the last good board configuration failed too: {e}");
                }
                Err(refused)
            }
            other => other,
        }
    }

    /// Tries to open the board again after an unplug.
    pub fn reconnect(&mut self) -> Result<(), BoardError> {
        self.connect()?;
        self.stats.reconnects += 1;
        Ok(())
    }

    pub fn is_connected(&self) -> bool {
        self.session.is_some()
    }

    /// What configuration did (including laser-safety clamps).
    pub fn init_report(&self) -> &InitReport {
        &self.report
    }

    pub fn serial(&self) -> Option<&str> {
        self.session.as_ref().and_then(|s| s.serial.as_deref())
    }

    pub fn stats(&self) -> StreamStats {
        let mut s = self.stats;
        if let Some(sess) = &self.session {
            s.assembler = sess.assembler.stats;
        }
        s
    }

    /// Sets the dark frame subtracted from every frame (DN, row-major).
    pub fn set_dark_dn(&mut self, dark: Option<Vec<f32>>) -> Result<(), BoardError> {
        Ok(self.decoder.set_dark_dn(dark)?)
    }

    /// Register access for diagnostics (status, temperatures).
    pub fn registers(&mut self) -> Option<&mut RegisterBus<UsbTransport>> {
        self.session.as_mut().map(|s| &mut s.bus)
    }

    /// The next decoded difference frame. The light sources are driven
    /// elsewhere (`light`); `illumination` is accepted for the Backend shape.
    pub fn next_frame(
        &mut self,
        _illumination: &Illumination,
        out: &mut Frame,
    ) -> Result<(), BoardError> {
        let Some(session) = self.session.as_mut() else {
            return Err(BoardError::DeviceUnavailable);
        };
        let deadline = Instant::now() + FRAME_WAIT;
        let mut detail = String::from("no data");
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let event = match session.stream.events.recv_timeout(left) {
                Ok(ev) => ev,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    return Err(BoardError::NoFrame {
                        waited_ms: FRAME_WAIT.as_millis(),
                        detail,
                    })
                }
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                    self.session = None;
                    return Err(BoardError::DeviceUnavailable);
                }
            };
            match event {
                StreamEvent::Data { bytes, short } => match session.assembler.push(&bytes, short) {
                    Assembled::Frame {
                        bytes,
                        frame_number,
                        ..
                    } => {
                        self.decoder.decode(&bytes, out)?;
                        out.sequence = self.sequence;
                        out.timestamp_us = self.started.elapsed().as_micros() as u64;
                        self.sequence += 1;
                        tracing::trace!(?frame_number, "frame");
                        return Ok(());
                    }
                    Assembled::Pending => {}
                    Assembled::Dropped(reason) => {
                        tracing::debug!(?reason, "frame dropped");
                        detail = format!("last frame dropped: {reason:?}");
                    }
                },
                StreamEvent::Timeout => self.stats.timeouts += 1,
                StreamEvent::HaltCleared => {
                    self.stats.halts_cleared += 1;
                    session.assembler.reset();
                    tracing::warn!("bulk endpoint halted; halt cleared, resynchronizing");
                }
                StreamEvent::Overflow => {
                    self.stats.overflows += 1;
                    session.assembler.reset();
                }
                StreamEvent::Error(e) => {
                    self.stats.errors += 1;
                    tracing::warn!(error = %e, "bulk transfer failed; retrying");
                    detail = e;
                }
                StreamEvent::Disconnected => {
                    tracing::warn!("board disconnected");
                    self.session = None;
                    return Err(BoardError::DeviceUnavailable);
                }
            }
        }
    }
}
