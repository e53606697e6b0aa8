//! The OPT8241-CDK device: open, configure, stream, decode, reconnect
//! (driven by the backend, `backend/board.rs`).
//!
//! `next_frame` has the shape of the daemon's `Backend::capture`; on
//! unplug it returns [`BoardError::DeviceUnavailable`] and the daemon keeps
//! its output open (showing "no signal") and calls [`Opt8241::reconnect`]
//! until the board is back. It waits for a frame at most [`FRAME_SLICE`]
//! per call ([`BoardError::NotYet`]), so the frame loop answers its
//! commands meanwhile; "no frame" ([`BoardError::NoFrame`]) is decided over
//! consecutive calls ([`FrameWait`]).

use std::sync::mpsc;
use std::time::{Duration, Instant};

use rusb::Context;
use sdi_core::modulation::Illumination;
use sdi_core::Frame;

use sdi_core::quad_phase::{PhaseAxis, PhaseSums};
use sdi_opt8241::configure::{configure, layout_of, ConfigError, InitReport};
use sdi_opt8241::depth_frame::depth_frame_bytes;
use sdi_opt8241::frame_assembler::{Assembled, AssemblerStats, DropReason, FrameAssembler};
use sdi_opt8241::protocol::{RegisterBus, Transport};
use sdi_opt8241::raw_quads::{DecodeError, QuadCombine, QuadDecoder};
use sdi_opt8241::saturation_probe::{
    DepthFrame, ProbeStats, ProbeWrite, SaturationProbe, PROBE_MAX_FAILURES,
};
use sdi_opt8241::BoardConfig;

use super::usb::{open_board, BoardSelector, BulkStream, StreamEvent, UsbError, UsbTransport};

mod error;
mod frame_wait;

pub use error::BoardError;
use frame_wait::{FrameWait, WaitStep};

/// Transfers queued at the host controller while streaming.
pub const DEFAULT_TRANSFERS_IN_FLIGHT: usize = 4;
/// How long `next_frame` waits for a frame (the SDK waits 2 s), over
/// consecutive calls.
pub const FRAME_WAIT: Duration = Duration::from_secs(2);
/// The longest one `next_frame` call waits before it returns
/// [`BoardError::NotYet`]: a silent, NAKing or trickling device holds the
/// frame loop, and the D-Bus calls it answers, no longer than this.
pub const FRAME_SLICE: Duration = Duration::from_millis(100);
/// Read timeout of one bulk transfer (the SDK uses 200 ms).
pub const READ_TIMEOUT: Duration = Duration::from_millis(200);
/// Unusable transfers (dropped frames, halts, overflows, errors) after which
/// `next_frame` gives up before [`FRAME_WAIT`]: a board in step loses at most
/// two frames to relock, while a device sending only garbage would
/// otherwise hold the frame loop, and every D-Bus call waiting on it, for
/// the whole wait on every capture.
pub const MAX_UNUSABLE_TRANSFERS: u32 = 8;

/// Stream counters for the daemon's Stats property.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    pub assembler: AssemblerStats,
    pub timeouts: u64,
    pub halts_cleared: u64,
    pub overflows: u64,
    pub errors: u64,
    pub reconnects: u64,
    pub saturation: ProbeStats,
}

struct Session {
    bus: RegisterBus<UsbTransport>,
    stream: BulkStream,
    assembler: FrameAssembler,
    serial: Option<String>,
}

/// A board found, opened, configured and streaming, not yet in use: what
/// opening yields, on whichever thread it ran.
pub struct Connection {
    context: Context,
    session: Session,
    report: InitReport,
}

impl Connection {
    fn open(
        selector: &BoardSelector,
        config: &BoardConfig,
        in_flight: usize,
    ) -> Result<Self, BoardError> {
        // A fresh libusb context rescans the bus: works without udev or
        // libusb hotplug support (e.g. inside minimal VMs and containers).
        let context = new_context()?;
        let open = open_board(&context, selector)?;
        let mut bus = RegisterBus::new(UsbTransport {
            handle: open.handle.clone(),
        });
        let report = configure(&mut bus, config).map_err(|e| match e {
            ConfigError::Protocol(p) => BoardError::from_protocol(p),
            other => BoardError::Config(other),
        })?;
        for c in &report.clamps {
            tracing::warn!(
                field = c.field,
                requested = c.requested,
                actual = c.actual,
                reason = c.reason,
                "board clamp"
            );
        }
        let layout = layout_of(config);
        let frame_bytes = layout.frame_bytes();
        let stream = BulkStream::start(
            open.handle,
            open.endpoint,
            frame_bytes,
            in_flight,
            READ_TIMEOUT,
        );
        let mut assembler = FrameAssembler::new(frame_bytes, config.frame_numbers);
        assembler.also_accept(depth_frame_bytes(layout.width, layout.height));
        Ok(Self {
            context,
            session: Session {
                bus,
                stream,
                assembler,
                serial: open.serial,
            },
            report,
        })
    }
}

/// A running OPT8241-CDK.
pub struct Opt8241 {
    context: Context,
    selector: BoardSelector,
    config: BoardConfig,
    decoder: QuadDecoder,
    /// Depth frames interleaved for the chip's saturation flags.
    probe: SaturationProbe,
    session: Option<Session>,
    /// The wait for the next frame, when a call returned
    /// [`BoardError::NotYet`] (cleared by a frame, an error or a new session).
    wait: Option<FrameWait>,
    report: InitReport,
    stats: StreamStats,
    sequence: u64,
    started: Instant,
    pub transfers_in_flight: usize,
    /// Sum each frame's (I, Q) for the phase calibration.
    measure_phase: bool,
    /// The sums of the last frame decoded while measuring.
    phase_sums: Option<PhaseSums>,
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
            probe: SaturationProbe::default(),
            config,
            session: None,
            wait: None,
            report: InitReport::default(),
            stats: StreamStats::default(),
            sequence: 0,
            started: Instant::now(),
            transfers_in_flight: DEFAULT_TRANSFERS_IN_FLIGHT,
            measure_phase: false,
            phase_sums: None,
        };
        board.connect()?;
        Ok(board)
    }

    fn connect(&mut self) -> Result<(), BoardError> {
        self.session = None;
        let c = Connection::open(&self.selector, &self.config, self.transfers_in_flight)?;
        self.install(c);
        Ok(())
    }

    /// Puts a connection to use: its session streams into this decoder.
    fn install(&mut self, c: Connection) {
        self.context = c.context;
        self.report = c.report;
        self.decoder.layout = layout_of(&self.config);
        self.decoder.frame_number_in_first_byte = self.config.frame_numbers;
        self.probe.reset();
        self.session = Some(c.session);
        self.wait = None;
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

    /// [`Opt8241::reconnect`] on a thread of its own: against a device that
    /// never answers a control request, or leaves UVC mode and never comes
    /// back, opening takes seconds, and the caller (the frame loop) must
    /// keep answering meanwhile. The receiver yields the outcome once; hand
    /// a connection to [`Opt8241::resume`].
    pub fn reconnect_in_background(&self) -> mpsc::Receiver<Result<Connection, BoardError>> {
        let (tx, rx) = mpsc::sync_channel(1);
        let (selector, config, in_flight) = (
            self.selector.clone(),
            self.config.clone(),
            self.transfers_in_flight,
        );
        let spawned = std::thread::Builder::new()
            .name("opt8241-open".into())
            .spawn(move || {
                let _ = tx.send(Connection::open(&selector, &config, in_flight));
            });
        if let Err(e) = spawned {
            let (tx, failed) = mpsc::sync_channel(1);
            let _ = tx.send(Err(BoardError::Usb(UsbError::Usb {
                op: "starting the thread that opens the board",
                error: e.to_string(),
            })));
            return failed;
        }
        rx
    }

    /// Streams from a connection [`Opt8241::reconnect_in_background`] made.
    pub fn resume(&mut self, c: Connection) {
        self.install(c);
        self.stats.reconnects += 1;
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
        s.saturation = self.probe.stats;
        s
    }

    /// Sets the dark frame subtracted from every frame (DN, row-major).
    pub fn set_dark_dn(&mut self, dark: Option<Vec<f32>>) -> Result<(), BoardError> {
        Ok(self.decoder.set_dark_dn(dark)?)
    }

    /// Decodes with the calibrated phase axis (`None`: quad 0 alone).
    pub fn set_phase_axis(&mut self, axis: Option<PhaseAxis>) {
        self.decoder.combine = axis.map_or(QuadCombine::Quad0, QuadCombine::Projected);
    }

    /// The axis frames are decoded with, if calibrated.
    pub fn phase_axis(&self) -> Option<PhaseAxis> {
        match self.decoder.combine {
            QuadCombine::Projected(axis) => Some(axis),
            _ => None,
        }
    }

    /// Starts or stops summing each frame's (I, Q) ([`Opt8241::take_phase_sums`]).
    pub fn measure_phase(&mut self, on: bool) {
        self.measure_phase = on;
        self.phase_sums = None;
    }

    /// The (I, Q) sums of the last frame, once, while measuring.
    pub fn take_phase_sums(&mut self) -> Option<PhaseSums> {
        self.phase_sums.take()
    }

    /// Register access for diagnostics (status, temperatures).
    pub fn registers(&mut self) -> Option<&mut RegisterBus<UsbTransport>> {
        self.session.as_mut().map(|s| &mut s.bus)
    }

    /// The next decoded difference frame. The light sources are driven
    /// elsewhere (`light`); `illumination` is accepted for the Backend shape.
    /// Waits at most [`FRAME_SLICE`]: [`BoardError::NotYet`] when no frame
    /// came and the wait for one ([`FRAME_WAIT`], across calls) goes on.
    pub fn next_frame(
        &mut self,
        _illumination: &Illumination,
        out: &mut Frame,
    ) -> Result<(), BoardError> {
        let r = self.next_frame_within(out);
        if !matches!(r, Err(BoardError::NotYet)) {
            self.wait = None;
        }
        r
    }

    fn next_frame_within(&mut self, out: &mut Frame) -> Result<(), BoardError> {
        let Some(session) = self.session.as_mut() else {
            return Err(BoardError::DeviceUnavailable);
        };
        let slice_end = Instant::now() + FRAME_SLICE;
        let wait = self
            .wait
            .get_or_insert_with(|| FrameWait::new(Instant::now()));
        loop {
            let now = Instant::now();
            let left = match wait.step(slice_end, now) {
                WaitStep::Wait(left) => left,
                WaitStep::Yield => return Err(BoardError::NotYet),
                WaitStep::GiveUp => return Err(wait.clone().no_frame(now)),
            };
            let event = match session.stream.events.recv_timeout(left) {
                Ok(ev) => ev,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => continue,
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
                        let l = self.decoder.layout;
                        if bytes.len() == depth_frame_bytes(l.width, l.height) {
                            let depth = self
                                .probe
                                .on_depth_frame(&bytes, l.width, l.height)
                                .map_err(|e| DecodeError::Length {
                                    expected: e.expected,
                                    got: e.got,
                                })?;
                            tracing::trace!(?frame_number, ?depth, "saturation flags");
                            let write = match depth {
                                DepthFrame::Expected(write) => write,
                                DepthFrame::Unasked(write) => {
                                    // Not a difference frame, and nobody asked:
                                    // a device sending only these ends the wait
                                    // like any unusable transfer.
                                    wait.unusable(
                                        "depth frames instead of raw quads",
                                        "frames of depth length, unasked".into(),
                                    );
                                    Some(write)
                                }
                            };
                            if let Some(write) = write {
                                if let Err(e) =
                                    probe_write(&mut session.bus, &mut self.probe, write)
                                {
                                    self.session = None;
                                    return Err(e);
                                }
                            }
                            continue;
                        }
                        self.decoder.decode(&bytes, out)?;
                        self.phase_sums = if self.measure_phase {
                            Some(self.decoder.phase_sums(&bytes)?)
                        } else {
                            None
                        };
                        self.probe.apply(&mut out.saturated.data);
                        if let Some(write) = self.probe.on_raw_frame() {
                            if let Err(e) = probe_write(&mut session.bus, &mut self.probe, write) {
                                self.session = None;
                                return Err(e);
                            }
                        }
                        out.sequence = self.sequence;
                        out.timestamp_us = self.started.elapsed().as_micros() as u64;
                        self.sequence += 1;
                        tracing::trace!(?frame_number, "frame");
                        return Ok(());
                    }
                    Assembled::Pending => {}
                    Assembled::Dropped(reason) => {
                        tracing::debug!(?reason, "frame dropped");
                        wait.unusable(
                            match reason {
                                DropReason::WrongLength { .. } => "frames of the wrong length",
                                DropReason::OutOfSequence { .. } | DropReason::Relocking => {
                                    "frames out of sequence"
                                }
                            },
                            format!("last frame dropped: {reason:?}"),
                        );
                    }
                },
                StreamEvent::Timeout => {
                    self.stats.timeouts += 1;
                    if let Some(write) = self.probe.on_no_frame() {
                        if let Err(e) = probe_write(&mut session.bus, &mut self.probe, write) {
                            self.session = None;
                            return Err(e);
                        }
                    }
                }
                StreamEvent::HaltCleared => {
                    self.stats.halts_cleared += 1;
                    session.assembler.reset();
                    // Logged by the caller as the cause of no frame, if it is one.
                    tracing::debug!("bulk endpoint halted; halt cleared, resynchronizing");
                    wait.unusable(
                        "bulk endpoint halted",
                        "the bulk endpoint halted; halt cleared".into(),
                    );
                }
                StreamEvent::Overflow => {
                    self.stats.overflows += 1;
                    session.assembler.reset();
                    wait.unusable(
                        "more data than asked",
                        "a transfer overflowed (babble)".into(),
                    );
                }
                StreamEvent::Error(e) => {
                    self.stats.errors += 1;
                    tracing::debug!(error = %e, "bulk transfer failed; retrying");
                    wait.unusable("bulk transfers failing", e);
                }
                StreamEvent::Disconnected => {
                    // The backend logs the loss (`backend::board`).
                    tracing::debug!("board disconnected");
                    self.session = None;
                    return Err(BoardError::DeviceUnavailable);
                }
            }
        }
    }
}

/// Performs a saturation probe's write. A lost board is
/// [`BoardError::DeviceUnavailable`]; any other failure is only logged: a
/// probe that did not start misses its depth frame, and a depth frame
/// after a switch back that did not take asks for raw quads again.
fn probe_write<T: Transport>(
    bus: &mut RegisterBus<T>,
    probe: &mut SaturationProbe,
    write: ProbeWrite,
) -> Result<(), BoardError> {
    if probe.take_gave_up_notice() {
        tracing::warn!(
            "saturation probe: the board sent no depth frame after output_mode = 0, {} times \
             in a row; pixels with both wells full are no longer flagged (only the 12-bit rails are)",
            PROBE_MAX_FAILURES
        );
    }
    let (field, value) = write.field_value();
    match bus.write_field(field, value) {
        Ok(_) => Ok(()),
        Err(e) if e.is_disconnect() => Err(BoardError::DeviceUnavailable),
        Err(e) => {
            tracing::debug!(
                "saturation probe: {} = {value} not written: {e}",
                field.name
            );
            Ok(())
        }
    }
}
