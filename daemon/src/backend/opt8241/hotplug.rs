//! libusb hotplug events for the board's USB IDs, when libusb delivers them.
//!
//! Debian's libusb takes its events from udev: without a running udevd
//! (minimal VMs, containers) it registers the callback but never calls it.
//! The copy rusb builds when no libusb-1.0-0-dev is installed has no
//! libudev and reads the kernel's own uevents, with or without udevd.
//! The backend therefore keeps scanning the bus as a fallback, slowly once
//! events have been seen to arrive, every 0.5 s until then
//! (`backend::board`).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use rusb::{Context, Device, HotplugBuilder, Registration, UsbContext};

use super::ids;

/// How long one `handle_events` call blocks before the stop flag is checked.
const EVENT_WAIT: Duration = Duration::from_millis(200);

/// A board (any mode of `udev/board-ids`) came or went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HotplugEvent {
    Arrived { product_id: u16 },
    Left { product_id: u16 },
}

struct Callback {
    tx: mpsc::Sender<HotplugEvent>,
    seen: Arc<AtomicU64>,
}

fn board_product(device: &Device<Context>) -> Option<u16> {
    let d = device.device_descriptor().ok()?;
    (d.vendor_id() == ids::VENDOR_ID
        && (d.product_id() == ids::PRODUCT_ID_BULK || d.product_id() == ids::PRODUCT_ID_UVC))
        .then(|| d.product_id())
}

impl rusb::Hotplug<Context> for Callback {
    fn device_arrived(&mut self, device: Device<Context>) {
        if let Some(product_id) = board_product(&device) {
            self.seen.fetch_add(1, Ordering::SeqCst);
            let _ = self.tx.send(HotplugEvent::Arrived { product_id });
        }
    }

    fn device_left(&mut self, device: Device<Context>) {
        if let Some(product_id) = board_product(&device) {
            self.seen.fetch_add(1, Ordering::SeqCst);
            let _ = self.tx.send(HotplugEvent::Left { product_id });
        }
    }
}

/// What a drain of the queued events found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Drained {
    pub arrived: bool,
    pub left: bool,
}

/// A registered hotplug callback with its event thread.
pub struct HotplugWatch {
    events: mpsc::Receiver<HotplugEvent>,
    seen: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    context: Context,
    thread: Option<JoinHandle<()>>,
    _registration: Registration<Context>,
}

impl HotplugWatch {
    /// Registers for the board's vendor ID. `Ok(None)` when this libusb has
    /// no hotplug support; `Err` when registering failed.
    pub fn start() -> Result<Option<Self>, rusb::Error> {
        if !rusb::has_hotplug() {
            return Ok(None);
        }
        let context = Context::new()?;
        let (tx, events) = mpsc::channel();
        let seen = Arc::new(AtomicU64::new(0));
        let registration = HotplugBuilder::new()
            .vendor_id(ids::VENDOR_ID)
            .enumerate(false)
            .register(
                &context,
                Box::new(Callback {
                    tx,
                    seen: seen.clone(),
                }),
            )?;
        let stop = Arc::new(AtomicBool::new(false));
        let (ctx, flag) = (context.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("opt8241-hotplug".into())
            .spawn(move || {
                while !flag.load(Ordering::SeqCst) {
                    if let Err(e) = ctx.handle_events(Some(EVENT_WAIT)) {
                        tracing::debug!("libusb hotplug events: {e}");
                        std::thread::sleep(EVENT_WAIT);
                    }
                }
            })
            .map_err(|_| rusb::Error::NoMem)?;
        Ok(Some(Self {
            events,
            seen,
            stop,
            context,
            thread: Some(thread),
            _registration: registration,
        }))
    }

    /// Events delivered since the start (board IDs only).
    pub fn events_seen(&self) -> u64 {
        self.seen.load(Ordering::SeqCst)
    }

    /// Takes every queued event.
    pub fn drain(&self) -> Drained {
        let mut d = Drained::default();
        while let Ok(ev) = self.events.try_recv() {
            match ev {
                HotplugEvent::Arrived { .. } => d.arrived = true,
                HotplugEvent::Left { .. } => d.left = true,
            }
        }
        d
    }

    /// Waits at most `timeout` for an arrival (queued events count too);
    /// true when one came.
    pub fn wait_arrival(&self, timeout: Duration) -> bool {
        if self.drain().arrived {
            return true;
        }
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.events.recv_timeout(left) {
                Ok(HotplugEvent::Arrived { .. }) => return true,
                Ok(HotplugEvent::Left { .. }) => {}
                Err(_) => return false,
            }
        }
    }
}

impl Drop for HotplugWatch {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.context.interrupt_handle_events();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
