//! Shared helpers for SDI's integration tests.

pub mod vm;
