//! Shared helpers for SDI's integration tests.
#![forbid(unsafe_code)]

pub mod bench;
pub mod board_emulator;
pub mod browser;
pub mod capture;
pub mod cdp;
pub mod clients;
pub mod dbus;
pub mod light_rig;
pub mod loopback;
pub mod m1_reference;
pub mod npy_file;
pub mod package;
pub mod pipewire;
pub mod process;
pub mod sdid_command;
pub mod sim_frames;
pub mod skip;
pub mod udev;
pub mod vm;
pub mod wait;
