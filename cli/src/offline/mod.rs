//! Offline tools that run the imaging core on simulator data (no daemon).

pub mod report;
