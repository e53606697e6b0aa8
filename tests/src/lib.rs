//! Shared helpers for SDI's integration tests.

pub mod bench;
pub mod board_emulator;
pub mod browser;
pub mod clients;
pub mod dbus;
pub mod loopback;
pub mod package;
pub mod pipewire;
pub mod process;
pub mod sim_frames;
pub mod skip;
pub mod udev;
pub mod vm;
