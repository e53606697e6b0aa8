//! The board being opened again on a thread of its own, off the frame loop.

use std::sync::mpsc;
use std::time::Duration;

use crate::backend::opt8241::device::Connection;
use crate::backend::opt8241::usb::UsbError;
use crate::backend::opt8241::BoardError;

/// The board being opened on its own thread ([`Opt8241::reconnect_in_background`]).
pub(super) struct Opening {
    pub(super) rx: mpsc::Receiver<Result<Connection, BoardError>>,
    /// Started by a hotplug arrival (else by a bus scan).
    pub(super) by_hotplug: bool,
    /// The outcome, once [`Opening::wait`] received it.
    pub(super) outcome: Option<Result<Connection, BoardError>>,
}

impl Opening {
    /// Waits at most `timeout` for the outcome.
    pub(super) fn wait(&mut self, timeout: Duration) {
        if self.outcome.is_none() {
            self.outcome = match self.rx.recv_timeout(timeout) {
                Ok(outcome) => Some(outcome),
                Err(mpsc::RecvTimeoutError::Timeout) => None,
                Err(mpsc::RecvTimeoutError::Disconnected) => Some(Err(Self::ended())),
            };
        }
    }

    /// The outcome, when there is one.
    pub(super) fn poll(&mut self) -> Option<Result<Connection, BoardError>> {
        self.outcome.take().or_else(|| match self.rx.try_recv() {
            Ok(outcome) => Some(outcome),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err(Self::ended())),
        })
    }

    fn ended() -> BoardError {
        BoardError::Usb(UsbError::Usb {
            op: "opening the board",
            error: "the thread opening it ended without an outcome".into(),
        })
    }
}
