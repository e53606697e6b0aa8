//! Control-transfer protocol of the OPT8241-CDK firmware (FX2 vendor requests).
//!
//! Register read: bmRequestType 0xC0 (vendor, device, IN), bRequest 0x08;
//! write: 0x40 (vendor, device, OUT), bRequest 0x09; wValue = I2C slave,
//! wIndex = register, 3 data bytes least significant first. Sources: firmware
//! `examples/opt8241-reference-fw/vendorcommand.c` (TFC_READ/TFC_WRITE) and SDK
//! `TI3DToF/VoxelUSBProgrammer.cpp` + `TintinCDKCamera.cpp` (request table).
//! The transport is a trait so the encoding is testable without a board.

use std::time::Duration;

use crate::registers::{Field, FieldRangeError, REGISTER_MASK};

/// Vendor request codes (firmware `vendorcommand.c`).
pub mod request {
    /// Read 3 bytes of an OPT9221 register.
    pub const TFC_READ: u8 = 0x08;
    /// Write 3 bytes of an OPT9221 register.
    pub const TFC_WRITE: u8 = 0x09;
    /// FX2 firmware version, 2 bytes.
    pub const FIRMWARE_VERSION: u8 = 0x1A;
    /// Board revision, 2 bytes (first is the revision).
    pub const BOARD_REVISION: u8 = 0x30;
    /// Calibration EEPROM size, 4 bytes little-endian.
    pub const EEPROM_SIZE: u8 = 0x31;
    /// Serial number string (variable length, default 22 bytes).
    pub const SERIAL_NUMBER: u8 = 0x32;
    /// Calibration EEPROM data.
    pub const EEPROM_DATA: u8 = 0x33;
}

/// bmRequestType of a vendor, device-recipient IN request.
pub const REQUEST_TYPE_VENDOR_IN: u8 = 0xC0;
/// bmRequestType of a vendor, device-recipient OUT request.
pub const REQUEST_TYPE_VENDOR_OUT: u8 = 0x40;
/// Data bytes of a register transfer.
pub const REGISTER_BYTES: usize = 3;

/// The 8-byte SETUP packet of a control transfer, as fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Setup {
    pub request_type: u8,
    pub request: u8,
    pub value: u16,
    pub index: u16,
    pub length: u16,
}

impl Setup {
    /// Register read of `address` (`slave << 8 | register`).
    pub fn register_read(address: u16) -> Self {
        Self {
            request_type: REQUEST_TYPE_VENDOR_IN,
            request: request::TFC_READ,
            value: address >> 8,
            index: address & 0xFF,
            length: REGISTER_BYTES as u16,
        }
    }

    /// Register write of `address`.
    pub fn register_write(address: u16) -> Self {
        Self {
            request_type: REQUEST_TYPE_VENDOR_OUT,
            request: request::TFC_WRITE,
            value: address >> 8,
            index: address & 0xFF,
            length: REGISTER_BYTES as u16,
        }
    }

    /// The register address a TFC request refers to.
    pub fn register_address(&self) -> u16 {
        ((self.value & 0xFF) << 8) | (self.index & 0xFF)
    }

    /// Parses the 8 bytes of a SETUP packet (all words little-endian).
    pub fn from_bytes(b: [u8; 8]) -> Self {
        Self {
            request_type: b[0],
            request: b[1],
            value: u16::from_le_bytes([b[2], b[3]]),
            index: u16::from_le_bytes([b[4], b[5]]),
            length: u16::from_le_bytes([b[6], b[7]]),
        }
    }

    pub fn is_in(&self) -> bool {
        self.request_type & 0x80 != 0
    }
}

/// A register value as the 3 bytes on the wire, least significant first.
pub fn encode_value(value: u32) -> [u8; REGISTER_BYTES] {
    let b = value.to_le_bytes();
    [b[0], b[1], b[2]]
}

/// The register value of 3 wire bytes.
pub fn decode_value(bytes: [u8; REGISTER_BYTES]) -> u32 {
    u32::from_le_bytes([bytes[0], bytes[1], bytes[2], 0])
}

/// What went wrong on the wire.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TransportError {
    #[error("timed out")]
    Timeout,
    #[error("endpoint stalled")]
    Stall,
    /// The device is gone (unplugged, reset): not retried.
    #[error("device disconnected")]
    Disconnected,
    #[error("{0}")]
    Other(String),
}

/// Anything that carries vendor control transfers to the board.
pub trait Transport {
    /// IN transfer into `buf`; returns the bytes received.
    fn control_in(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, TransportError>;
    /// OUT transfer of `data`; returns the bytes sent.
    fn control_out(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, TransportError>;
}

/// Register-level errors.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProtocolError {
    #[error(
        "request 0x{request:02x} for 0x{address:04x} failed after {attempts} attempts: {source}"
    )]
    Transport {
        request: u8,
        address: u16,
        attempts: u32,
        source: TransportError,
    },
    #[error("request 0x{request:02x} for 0x{address:04x}: short transfer, {got} of {expected} bytes after {attempts} attempts")]
    Short {
        request: u8,
        address: u16,
        expected: usize,
        got: usize,
        attempts: u32,
    },
    #[error(transparent)]
    Range(#[from] FieldRangeError),
    #[error("field {0} is read-only")]
    ReadOnly(&'static str),
    #[error("serial number is not text: {0:02x?}")]
    BadSerial(Vec<u8>),
}

impl ProtocolError {
    /// True when the board is gone (the daemon then reports DeviceUnavailable).
    pub fn is_disconnect(&self) -> bool {
        matches!(
            self,
            ProtocolError::Transport {
                source: TransportError::Disconnected,
                ..
            }
        )
    }
}

/// One field write and what the board kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FieldWrite {
    pub field: Field,
    pub requested: u32,
    pub actual: u32,
}

impl FieldWrite {
    /// The board (firmware laser-safety masks) kept a different value.
    pub fn clamped(&self) -> bool {
        self.requested != self.actual
    }
}

/// Register access over a [`Transport`], with retries of short or failed
/// control transfers (short control reads are a known Linux issue with the
/// SDK; each attempt is logged).
pub struct RegisterBus<T> {
    transport: T,
    /// Attempts per transfer (>= 1).
    pub attempts: u32,
    pub timeout: Duration,
}

impl<T: Transport> RegisterBus<T> {
    pub fn new(transport: T) -> Self {
        Self {
            transport,
            attempts: 3,
            timeout: Duration::from_millis(1000),
        }
    }

    pub fn transport(&self) -> &T {
        &self.transport
    }

    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    pub fn into_transport(self) -> T {
        self.transport
    }

    /// Reads `buf.len()` bytes of a vendor IN request, retrying short reads.
    fn read_exact(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        buf: &mut [u8],
    ) -> Result<(), ProtocolError> {
        let expected = buf.len();
        self.with_retries(request, value, index, expected, |t, timeout| {
            t.control_in(request, value, index, buf, timeout)
        })
    }

    fn write_all(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        data: &[u8],
    ) -> Result<(), ProtocolError> {
        self.with_retries(request, value, index, data.len(), |t, timeout| {
            t.control_out(request, value, index, data, timeout)
        })
    }

    /// Runs one control `transfer` of `expected` bytes up to `attempts`
    /// times: short transfers and transport errors are retried (Linux drivers
    /// return short control reads now and then), a disconnect is final.
    fn with_retries(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        expected: usize,
        mut transfer: impl FnMut(&mut T, Duration) -> Result<usize, TransportError>,
    ) -> Result<(), ProtocolError> {
        let address = ((value & 0xFF) << 8) | (index & 0xFF);
        let attempts = self.attempts.max(1);
        let mut last = None;
        for attempt in 1..=attempts {
            match transfer(&mut self.transport, self.timeout) {
                Ok(n) if n == expected => return Ok(()),
                // Per attempt at debug: the caller logs the outcome once.
                Ok(n) => {
                    tracing::debug!(request, address, got = n, attempt, "short control transfer");
                    last = Some(ProtocolError::Short {
                        request,
                        address,
                        expected,
                        got: n,
                        attempts: attempt,
                    });
                }
                Err(TransportError::Disconnected) => {
                    return Err(ProtocolError::Transport {
                        request,
                        address,
                        attempts: attempt,
                        source: TransportError::Disconnected,
                    })
                }
                Err(e) => {
                    tracing::debug!(request, address, attempt, error = %e, "control transfer failed");
                    last = Some(ProtocolError::Transport {
                        request,
                        address,
                        attempts: attempt,
                        source: e,
                    });
                }
            }
        }
        Err(last.unwrap_or(ProtocolError::Short {
            request,
            address,
            expected,
            got: 0,
            attempts,
        }))
    }

    /// Whole 24-bit register.
    pub fn read_register(&mut self, address: u16) -> Result<u32, ProtocolError> {
        let s = Setup::register_read(address);
        let mut buf = [0u8; REGISTER_BYTES];
        self.read_exact(s.request, s.value, s.index, &mut buf)?;
        Ok(decode_value(buf))
    }

    /// Whole 24-bit register (bits above 23 are dropped).
    pub fn write_register(&mut self, address: u16, value: u32) -> Result<(), ProtocolError> {
        let s = Setup::register_write(address);
        self.write_all(
            s.request,
            s.value,
            s.index,
            &encode_value(value & REGISTER_MASK),
        )
    }

    pub fn read_field(&mut self, field: Field) -> Result<u32, ProtocolError> {
        Ok(field.extract(self.read_register(field.address)?))
    }

    /// Read-modify-write of one field, then a read-back: the returned
    /// [`FieldWrite`] says what the board kept (laser-safety clamps show up
    /// as `requested != actual`; they are reported, never worked around).
    pub fn write_field(&mut self, field: Field, value: u32) -> Result<FieldWrite, ProtocolError> {
        if field.read_only {
            return Err(ProtocolError::ReadOnly(field.name));
        }
        let current = self.read_register(field.address)?;
        let next = field.insert(current, value)?;
        self.write_register(field.address, next)?;
        let actual = self.read_field(field)?;
        // The caller reports clamps (`configure::InitReport`) once per configuration.
        if actual != value {
            tracing::debug!(
                field = field.name,
                requested = value,
                actual,
                "board kept a different value"
            );
        }
        Ok(FieldWrite {
            field,
            requested: value,
            actual,
        })
    }

    /// FX2 firmware version (major, minor).
    pub fn firmware_version(&mut self) -> Result<(u8, u8), ProtocolError> {
        let mut b = [0u8; 2];
        self.read_exact(request::FIRMWARE_VERSION, 0, 0, &mut b)?;
        Ok((b[0], b[1]))
    }

    pub fn board_revision(&mut self) -> Result<u8, ProtocolError> {
        let mut b = [0u8; 2];
        self.read_exact(request::BOARD_REVISION, 0, 0, &mut b)?;
        Ok(b[0])
    }

    /// Serial number from the FX2 boot EEPROM (variable length).
    pub fn serial_number(&mut self) -> Result<String, ProtocolError> {
        let mut b = [0u8; 32];
        let n = self
            .transport
            .control_in(request::SERIAL_NUMBER, 0, 0, &mut b, self.timeout)
            .map_err(|source| ProtocolError::Transport {
                request: request::SERIAL_NUMBER,
                address: 0,
                attempts: 1,
                source,
            })?;
        let raw = &b[..n.min(b.len())];
        let text = std::str::from_utf8(raw).map_err(|_| ProtocolError::BadSerial(raw.to_vec()))?;
        Ok(text.trim_end_matches('\0').trim().to_string())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use std::collections::HashMap;

    use super::*;
    use crate::registers::{field, safety};

    /// A fake board: a register file behind the vendor requests, with the
    /// firmware's laser-safety masks, a log of every SETUP and optional
    /// injected short reads.
    #[derive(Default)]
    pub struct FakeBoard {
        pub registers: HashMap<u16, u32>,
        pub log: Vec<(Setup, Vec<u8>)>,
        pub short_reads_left: u32,
        pub disconnected: bool,
    }

    impl FakeBoard {
        fn mask(address: u16, mut value: u32) -> u32 {
            if address == field::INTG_DUTY_CYCLE.address {
                if value & 0x3F > safety::INTG_DUTY_CYCLE_MAX {
                    value = (value & !0x3F) | safety::INTG_DUTY_CYCLE_MAX;
                }
                value &= !(1 << 22);
            }
            if address == field::PIX_CNT_MAX.address
                && value & 0x3F_0000 == 0
                && value & 0xFFFF < safety::PIX_CNT_MAX_MIN
            {
                value = (value & !0xFFFF) | safety::PIX_CNT_MAX_MIN;
            }
            value
        }
    }

    impl Transport for FakeBoard {
        fn control_in(
            &mut self,
            request: u8,
            value: u16,
            index: u16,
            buf: &mut [u8],
            _timeout: Duration,
        ) -> Result<usize, TransportError> {
            if self.disconnected {
                return Err(TransportError::Disconnected);
            }
            let s = Setup {
                request_type: REQUEST_TYPE_VENDOR_IN,
                request,
                value,
                index,
                length: buf.len() as u16,
            };
            self.log.push((s, Vec::new()));
            if self.short_reads_left > 0 {
                self.short_reads_left -= 1;
                return Ok(1);
            }
            match request {
                request::TFC_READ => {
                    let v = self
                        .registers
                        .get(&s.register_address())
                        .copied()
                        .unwrap_or(0);
                    buf[..3].copy_from_slice(&encode_value(v));
                    Ok(3)
                }
                request::FIRMWARE_VERSION => {
                    buf[..2].copy_from_slice(&[0x00, 0x11]);
                    Ok(2)
                }
                request::SERIAL_NUMBER => {
                    let sn = b"CDK-0042";
                    buf[..sn.len()].copy_from_slice(sn);
                    Ok(sn.len())
                }
                _ => Err(TransportError::Stall),
            }
        }

        fn control_out(
            &mut self,
            request: u8,
            value: u16,
            index: u16,
            data: &[u8],
            _timeout: Duration,
        ) -> Result<usize, TransportError> {
            if self.disconnected {
                return Err(TransportError::Disconnected);
            }
            let s = Setup {
                request_type: REQUEST_TYPE_VENDOR_OUT,
                request,
                value,
                index,
                length: data.len() as u16,
            };
            self.log.push((s, data.to_vec()));
            if request != request::TFC_WRITE || data.len() != 3 {
                return Err(TransportError::Stall);
            }
            let a = s.register_address();
            let v = Self::mask(a, decode_value([data[0], data[1], data[2]]));
            self.registers.insert(a, v);
            Ok(3)
        }
    }

    #[test]
    fn setup_encoding_matches_the_firmware() {
        let r = Setup::register_read(0x5C4C);
        assert_eq!(
            (r.request_type, r.request, r.value, r.index, r.length),
            (0xC0, 0x08, 0x5C, 0x4C, 3)
        );
        let w = Setup::register_write(0x5882);
        assert_eq!(
            (w.request_type, w.request, w.value, w.index, w.length),
            (0x40, 0x09, 0x58, 0x82, 3)
        );
        let bytes = [0xC0, 0x08, 0x5C, 0x00, 0x4C, 0x00, 0x03, 0x00];
        assert_eq!(Setup::from_bytes(bytes), r);
        assert_eq!(r.register_address(), 0x5C4C);
        assert_eq!(encode_value(0x01_D4C0), [0xC0, 0xD4, 0x01]);
        assert_eq!(decode_value([0xC0, 0xD4, 0x01]), 0x01_D4C0);
    }

    #[test]
    fn write_field_is_read_modify_write_with_readback() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        bus.transport_mut().registers.insert(0x5883, 0x44);
        let w = bus.write_field(field::QUAD_CNT_MAX, 6).unwrap();
        assert!(!w.clamped());
        assert_eq!(bus.transport().registers[&0x5883], 0x46);
        let log = &bus.transport().log;
        // read, write (3 bytes LE), read back
        assert_eq!(log.len(), 3);
        assert_eq!(log[0].0, Setup::register_read(0x5883));
        assert_eq!(log[1].0, Setup::register_write(0x5883));
        assert_eq!(log[1].1, vec![0x46, 0x00, 0x00]);
        assert_eq!(log[2].0, Setup::register_read(0x5883));
    }

    #[test]
    fn safety_clamps_are_reported() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        let w = bus.write_field(field::INTG_DUTY_CYCLE, 40).unwrap();
        assert!(w.clamped());
        assert_eq!(w.actual, 20);
        let w = bus.write_field(field::PIX_CNT_MAX, 30_000).unwrap();
        assert_eq!((w.requested, w.actual), (30_000, 60_000));
    }

    #[test]
    fn short_reads_are_retried_then_reported() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        bus.transport_mut().registers.insert(0x5C25, 0xF00);
        bus.transport_mut().short_reads_left = 2;
        assert_eq!(bus.read_field(field::OUTPUT_MODE).unwrap(), 15);
        bus.transport_mut().short_reads_left = 5;
        let e = bus.read_register(0x5C25).unwrap_err();
        assert!(
            matches!(
                e,
                ProtocolError::Short {
                    expected: 3,
                    got: 1,
                    attempts: 3,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn disconnect_is_not_retried_and_is_typed() {
        let mut bus = RegisterBus::new(FakeBoard {
            disconnected: true,
            ..Default::default()
        });
        let e = bus.read_register(0x5880).unwrap_err();
        assert!(e.is_disconnect());
        assert!(matches!(e, ProtocolError::Transport { attempts: 1, .. }));
    }

    #[test]
    fn read_only_fields_are_refused() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        let e = bus.write_field(field::TSENSOR, 1).unwrap_err();
        assert_eq!(e, ProtocolError::ReadOnly("tsensor"));
        assert!(bus.transport().log.is_empty());
    }

    #[test]
    fn identity_requests() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        assert_eq!(bus.firmware_version().unwrap(), (0, 0x11));
        assert_eq!(bus.serial_number().unwrap(), "CDK-0042");
    }
}
