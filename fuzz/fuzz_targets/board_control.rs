//! Fuzz target: what sdid makes of the board's control-transfer replies
//! (`RegisterBus`, `configure`, `read_status`; opt8241/src/protocol.rs,
//! configure.rs and health.rs).
//!
//! Input: the board's side of every control transfer in turn: a stall, a
//! timeout, a disconnect, another error, or a reply of any length (short,
//! empty, full) and content. sdid's requests run against it: identity
//! (firmware version, revision, serial number), the whole init sequence
//! with its read-backs, the status registers and single field writes.
//! Invariant: no panic or abort; every failure is a typed `ProtocolError`
//! or `ConfigError`; each request makes at most `attempts` transfers, so
//! the time is bounded by the number of requests; no allocation grows with
//! the replies (the serial number is read into 32 bytes).
#![no_main]

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use sdi_fuzz::{arbitrary, Unstructured};
use sdi_opt8241::configure::configure;
use sdi_opt8241::health::read_status;
use sdi_opt8241::protocol::{RegisterBus, Transport, TransportError};
use sdi_opt8241::registers::field;
use sdi_opt8241::BoardConfig;

/// A board whose every reply comes from the fuzzer's bytes; out of bytes,
/// it is unplugged.
struct HostileBoard<'a> {
    u: Unstructured<'a>,
    transfers: usize,
}

impl HostileBoard<'_> {
    fn outcome(&mut self, len: usize) -> Result<usize, TransportError> {
        self.transfers += 1;
        let pick: u8 = self
            .u
            .arbitrary()
            .map_err(|_| TransportError::Disconnected)?;
        match pick {
            0 => Err(TransportError::Timeout),
            1 => Err(TransportError::Stall),
            2 => Err(TransportError::Disconnected),
            3 => Err(TransportError::Other("overflow".into())),
            // libusb never reports more bytes than the buffer holds.
            4..=31 => Ok(usize::from(pick - 4).min(len)),
            _ => Ok(len),
        }
    }
}

impl Transport for HostileBoard<'_> {
    fn control_in(
        &mut self,
        _request: u8,
        _value: u16,
        _index: u16,
        buf: &mut [u8],
        _timeout: Duration,
    ) -> Result<usize, TransportError> {
        let n = self.outcome(buf.len())?;
        for b in &mut buf[..n] {
            *b = self.u.arbitrary().unwrap_or(0);
        }
        Ok(n)
    }

    fn control_out(
        &mut self,
        _request: u8,
        _value: u16,
        _index: u16,
        data: &[u8],
        _timeout: Duration,
    ) -> Result<usize, TransportError> {
        self.outcome(data.len())
    }
}

fn run(data: &[u8]) -> arbitrary::Result<()> {
    let mut bus = RegisterBus::new(HostileBoard {
        u: Unstructured::new(data),
        transfers: 0,
    });
    let attempts = bus.attempts as usize;
    let mut requests = 0;
    let _ = bus.firmware_version();
    let _ = bus.board_revision();
    if let Ok(serial) = bus.serial_number() {
        assert!(serial.len() <= 32);
    }
    requests += 3;
    let _ = configure(&mut bus, &BoardConfig::default());
    let _ = read_status(&mut bus);
    for f in [field::TG_DIS, field::TSENSOR, field::MASTER_PLL_LOCK] {
        let value = bus.transport_mut().u.arbitrary::<u32>()?;
        let _ = bus.write_field(f, value);
    }
    requests += 3 * 3;
    let transfers = bus.transport().transfers;
    // configure and read_status: bounded by their register count, not by the board.
    assert!(
        transfers <= (requests + 400) * attempts,
        "{transfers} transfers"
    );
    Ok(())
}

fuzz_target!(|data: &[u8]| {
    let _ = run(data);
});
