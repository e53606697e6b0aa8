//! The output thread: owns the sink, takes frames from a two-slot queue and
//! drops (and counts) frames when the reader is slower than the sensor.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use super::{Sink, SinkInfo};
use crate::monotonic::monotonic_now_us;
use sdi_core::display::DisplayMap;
use sdi_core::mode::{ModeId, ModeOutput};

enum Msg {
    Frame(Arc<ModeOutput>, DisplayMap, Option<ModeId>),
    /// The card, with the timestamp the frame loop chose for it.
    NoSignal(u64),
}

/// Sending side, held by the frame loop.
pub struct Output {
    tx: Option<SyncSender<Msg>>,
    info: SinkInfo,
    dropped: Arc<AtomicU64>,
    watchers: Arc<AtomicU32>,
    /// Mode of the frames sent from now on ([`Output::set_mode`]).
    mode: Option<ModeId>,
    thread: Option<JoinHandle<()>>,
}

/// Trace target of one line per frame written: the mode and the time from
/// its capture timestamp to the end of the sink's write (sdid's own
/// latency: capture, processing, queue, rendering and publishing).
pub const AGE_LOG: &str = "sdid::output::age";

/// [`Output::watchers`] not known (the sink cannot tell).
const WATCHERS_UNKNOWN: u32 = u32::MAX;
/// How often the output thread refreshes the watcher count while idle.
const WATCHERS_POLL: Duration = Duration::from_millis(100);

impl Output {
    pub fn spawn(mut sink: Box<dyn Sink>) -> std::io::Result<Self> {
        let info = sink.info();
        let (tx, rx) = sync_channel::<Msg>(2);
        let watchers = Arc::new(AtomicU32::new(WATCHERS_UNKNOWN));
        let seen = watchers.clone();
        let thread = std::thread::Builder::new()
            .name("sdid-output".into())
            .spawn(move || {
                let mut failing = false;
                loop {
                    let msg = rx.recv_timeout(WATCHERS_POLL);
                    let count = sink.watchers().unwrap_or(WATCHERS_UNKNOWN);
                    seen.store(count, Ordering::Relaxed);
                    let msg = match msg {
                        Ok(msg) => msg,
                        Err(RecvTimeoutError::Timeout) => continue,
                        Err(RecvTimeoutError::Disconnected) => break,
                    };
                    let r = match msg {
                        Msg::Frame(out, display, mode) => {
                            if let Some(m) = mode {
                                sink.set_mode(m);
                            }
                            let r = sink.write(&out, &display);
                            if r.is_ok()
                                && tracing::enabled!(target: AGE_LOG, tracing::Level::TRACE)
                            {
                                let age_us = monotonic_now_us().saturating_sub(out.timestamp_us);
                                tracing::trace!(
                                    target: AGE_LOG,
                                    mode = %mode.map_or("", ModeId::name),
                                    capture_to_write_us = age_us,
                                    "written"
                                );
                            }
                            r
                        }
                        Msg::NoSignal(timestamp_us) => sink.write_no_signal(timestamp_us),
                    };
                    match r {
                        Ok(()) => failing = false,
                        Err(e) if !failing => {
                            tracing::warn!("output sink: {e}");
                            failing = true;
                        }
                        Err(_) => {}
                    }
                }
            })?;
        Ok(Self {
            tx: Some(tx),
            info,
            dropped: Arc::new(AtomicU64::new(0)),
            watchers,
            mode: None,
            thread: Some(thread),
        })
    }

    pub fn info(&self) -> &SinkInfo {
        &self.info
    }

    /// Frames not shown because the output was busy.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Readers watching the output, as the sink last reported (refreshed
    /// with every frame and at least every 100 ms); `None` when the sink
    /// cannot tell (y4m, v4l2loopback 0.12.x).
    pub fn watchers(&self) -> Option<u32> {
        match self.watchers.load(Ordering::Relaxed) {
            WATCHERS_UNKNOWN => None,
            n => Some(n),
        }
    }

    /// Tags the frames sent from now on with `mode`.
    pub fn set_mode(&mut self, mode: ModeId) {
        self.mode = Some(mode);
    }

    /// Queues a frame; never blocks.
    pub fn send(&self, out: Arc<ModeOutput>, display: DisplayMap) {
        self.try_send(Msg::Frame(out, display, self.mode));
    }

    /// Queues the "no signal" card stamped `timestamp_us`; never blocks.
    pub fn send_no_signal(&self, timestamp_us: u64) {
        self.try_send(Msg::NoSignal(timestamp_us));
    }

    fn try_send(&self, msg: Msg) {
        if let Some(tx) = &self.tx {
            if let Err(TrySendError::Full(_)) = tx.try_send(msg) {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        self.tx = None;
        // The thread may be blocked in a write to a stalled reader; do not wait forever.
        if let Some(t) = self.thread.take() {
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}
