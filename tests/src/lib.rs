//! Shared helpers for SDI's integration tests.

pub mod board_emulator;
pub mod vm;
