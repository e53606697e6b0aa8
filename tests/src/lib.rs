//! Shared helpers for SDI's integration tests.

pub mod dbus;
pub mod vm;
