//! What the frame source is doing right now, shared between the backend (the
//! only writer) and the D-Bus object (readers): which backend delivers frames,
//! from which device, and whether the device is there at all.

use std::sync::{Arc, Mutex};

use sdi_opt8241::health::BoardHealth;

/// A snapshot of the source's state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceStatus {
    /// Backend delivering frames now ("opt8241", or "sim" while it stands in).
    pub backend: String,
    /// Human-readable device.
    pub device: String,
    /// False while the board is unplugged (and nothing stands in for it).
    pub available: bool,
    /// Why, when something is off (unplug, clamps, USB errors).
    pub detail: String,
    /// Temperatures and overflows; None before the first poll and for
    /// sources without them.
    pub health: Option<BoardHealth>,
}

/// Cheap to clone; readers never block the frame loop for long.
#[derive(Debug, Clone)]
pub struct StatusHandle(Arc<Mutex<DeviceStatus>>);

impl StatusHandle {
    pub fn new(status: DeviceStatus) -> Self {
        Self(Arc::new(Mutex::new(status)))
    }

    pub fn get(&self) -> DeviceStatus {
        match self.0.lock() {
            Ok(s) => s.clone(),
            Err(p) => p.into_inner().clone(),
        }
    }

    pub fn update(&self, f: impl FnOnce(&mut DeviceStatus)) {
        match self.0.lock() {
            Ok(mut s) => f(&mut s),
            Err(p) => f(&mut p.into_inner()),
        }
    }
}
