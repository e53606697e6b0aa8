//! The OPT8241-CDK without I/O, shared by sdid (which runs it over USB),
//! sdictl (which prints the open plan offline) and the fuzz targets.
//!
//! The chip as data: the OPT9221 register map ([`registers`]), what a
//! configuration asks ([`config`], [`roi`]) and what the chip allows
//! ([`limits`], [`pll`], [`range`]), and the exact register sequence
//! that opens and configures it ([`plan`]).
//!
//! The board's side of the wire, over a [`protocol::Transport`] that sdid
//! implements with libusb: the vendor control requests ([`protocol`]),
//! the open plan executed ([`configure`]), temperatures and overflows
//! polled ([`health`]); the bulk stream cut into frames
//! ([`frame_assembler`]) and raw quads decoded to the difference frame
//! ([`raw_quads`]); the depth frame ([`depth_frame`]) the saturation probe
//! ([`saturation_probe`]) interleaves for the chip's saturation flags;
//! the choices made from a device's USB descriptors ([`descriptors`]) and
//! the UVC -> bulk switch request ([`uvc_switch`]).
//!
//! No libusb here: sdid's `daemon/src/backend/opt8241/` does the I/O.
//! Sources of every register and request: `docs/hardware.md`.
#![forbid(unsafe_code)]

pub mod config;
pub mod configure;
pub mod depth_frame;
pub mod descriptors;
pub mod frame_assembler;
pub mod health;
pub mod limits;
pub mod plan;
pub mod pll;
pub mod protocol;
pub mod range;
pub mod raw_quads;
pub mod registers;
pub mod roi;
pub mod saturation_probe;
pub mod uvc_switch;

pub use config::BoardConfig;
pub use limits::BoardLimits;
pub use plan::{open_plan, Plan, Step};
pub use pll::PllSettings;
pub use range::{OutOfRange, Range};
pub use roi::Roi;
