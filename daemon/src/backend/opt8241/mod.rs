//! TI OPT8241-CDK over USB (vendor bulk mode, USB 0451:9105).
//!
//! Layers, each usable alone: [`registers`] (OPT9221 field map, with the
//! limits and the open plan in `sdi_opt8241`, shared with sdictl) ->
//! [`protocol`] (vendor control requests over a [`protocol::Transport`]) ->
//! [`init`] (executes the open plan); [`frame`]
//! (raw quads -> difference frame, alignment); [`saturation`] (the depth
//! frame interleaved for the chip's saturation flags); [`usb`] (libusb transport,
//! discovery, UVC -> bulk switch, bulk stream); [`hotplug`] (libusb hotplug
//! events); [`board`] ties them into the backend.
//! Sources of every register and request: `docs/hardware.md`.

pub mod board;
pub mod hotplug;
pub mod ids;
pub mod usb;

pub use board::{BoardError, Opt8241};
pub use usb::BoardSelector;
