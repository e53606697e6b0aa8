//! What can go wrong with the board, and the cause each error is logged by.

use sdi_opt8241::configure::ConfigError;
use sdi_opt8241::protocol::{ProtocolError, TransportError};
use sdi_opt8241::raw_quads::DecodeError;

use crate::backend::opt8241::usb::UsbError;

/// An error of the board: opening, configuring, streaming or decoding.
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
    NoFrame {
        waited_ms: u128,
        /// What came instead, in a few words (the key of its log line).
        cause: &'static str,
        detail: String,
    },
    /// No frame within [`FRAME_SLICE`](super::FRAME_SLICE), and
    /// [`FRAME_WAIT`](super::FRAME_WAIT) is not over:
    /// call `next_frame` again (not a failure, never logged).
    #[error("no frame yet")]
    NotYet,
}

impl BoardError {
    /// What went wrong, without the details that vary from one occurrence
    /// to the next (addresses, byte counts, attempts): the key of
    /// log-on-change ([`CauseLog`]).
    pub fn cause(&self) -> &'static str {
        match self {
            BoardError::Usb(u) => match u {
                UsbError::NotFound { .. } => "no board",
                UsbError::Ambiguous { .. } | UsbError::AmbiguousUvc { .. } => "several boards",
                UsbError::UvcSwitch { .. } => "UVC switch failed",
                UsbError::UvcSwitchTimeout { .. } => "UVC switch timed out",
                UsbError::Access => "permission denied",
                UsbError::NoBulkInEndpoint { .. } => "no bulk IN endpoint",
                UsbError::Busy => "busy",
                UsbError::Disconnected => "disconnected",
                UsbError::Usb { op, .. } => op,
            },
            BoardError::Protocol(p) => match p {
                ProtocolError::Transport { source, .. } => match source {
                    TransportError::Timeout => "control transfer timed out",
                    TransportError::Stall => "control transfer stalled",
                    TransportError::Disconnected => "disconnected",
                    TransportError::Other(_) => "control transfer failed",
                },
                ProtocolError::Short { .. } => "short control reply",
                ProtocolError::Range(_) | ProtocolError::ReadOnly(_) => "register access refused",
                ProtocolError::BadSerial(_) => "serial number not text",
            },
            BoardError::Config(_) => "configuration refused",
            BoardError::Decode(_) => "frame not decodable",
            BoardError::DeviceUnavailable => "disconnected",
            BoardError::NoFrame { cause, .. } => cause,
            BoardError::NotYet => "no frame yet",
        }
    }

    pub(super) fn from_protocol(e: ProtocolError) -> Self {
        if e.is_disconnect() {
            BoardError::DeviceUnavailable
        } else {
            BoardError::Protocol(e)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_does_not_vary_with_the_details() {
        let short = |got, attempts| {
            BoardError::Protocol(ProtocolError::Short {
                request: 8,
                address: 0x5880,
                expected: 3,
                got,
                attempts,
            })
        };
        assert_eq!(short(1, 3).cause(), short(2, 1).cause());
        let stall = BoardError::Protocol(ProtocolError::Transport {
            request: 8,
            address: 0x5C4C,
            attempts: 3,
            source: TransportError::Stall,
        });
        assert_ne!(stall.cause(), short(1, 3).cause());
        let no_frame = |cause, detail: &str| BoardError::NoFrame {
            waited_ms: 2000,
            cause,
            detail: detail.into(),
        };
        assert_eq!(
            no_frame("frames of the wrong length", "got 7").cause(),
            no_frame("frames of the wrong length", "got 9").cause()
        );
        assert_ne!(
            no_frame("frames of the wrong length", "").cause(),
            no_frame("bulk endpoint halted", "").cause()
        );
        assert_eq!(
            BoardError::Usb(UsbError::NoBulkInEndpoint { interface: 0 }).cause(),
            "no bulk IN endpoint"
        );
    }
}
