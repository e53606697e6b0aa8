//! Offline tools: run the imaging core without the daemon.

pub mod sim;
