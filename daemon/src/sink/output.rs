//! The output threads: one per sink, each owning its sink, taking frames
//! from its own two-slot queue and dropping (and counting) frames when its
//! reader is slower than the sensor.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::Duration;

use super::{Sink, SinkInfo, SinkSet};
use crate::monotonic::monotonic_now_us;
use crate::out_frame::OutFrame;
use crate::queue::Bounded;

#[derive(Clone)]
enum Msg {
    Frame(Arc<OutFrame>),
    /// The card, with the timestamp the frame loop chose for it.
    NoSignal(u64),
}

/// Frames queued per sink: one being written, one waiting.
const QUEUE_FRAMES: usize = 2;

/// One sink on its own thread behind its own queue, so a sink that stalls
/// (a reader holding the loopback ring, a full camera socket) delays
/// neither the frame loop nor the other sinks.
struct Lane {
    queue: Bounded<Msg>,
    watchers: Arc<AtomicU32>,
}

/// Sending side, held by the frame loop: every sink of the set gets every
/// frame (the same [`OutFrame`], its pictures rendered once), each at its
/// own pace.
pub struct Output {
    lanes: Vec<Lane>,
    info: SinkInfo,
    also: Vec<SinkInfo>,
}

/// Trace target of one line per frame written: the mode and the time from
/// its capture timestamp to the end of the sink's write (sdid's own
/// latency: capture, processing, queue, rendering and publishing).
pub const AGE_LOG: &str = "sdid::output::age";

/// [`Output::watchers`] not known (the sink cannot tell).
const WATCHERS_UNKNOWN: u32 = u32::MAX;
/// How often the output thread refreshes the watcher count while idle.
const WATCHERS_POLL: Duration = Duration::from_millis(100);

impl Lane {
    fn spawn(sink: Box<dyn Sink>) -> std::io::Result<Self> {
        let watchers = Arc::new(AtomicU32::new(WATCHERS_UNKNOWN));
        let seen = watchers.clone();
        let name = format!("sdid-output-{}", sink.info().kind);
        let queue = Bounded::spawn(&name, QUEUE_FRAMES, move |rx| feed(sink, &rx, &seen))?;
        Ok(Self { queue, watchers })
    }
}

/// The output thread: writes what comes until the queue closes,
/// refreshing the watcher count at least every [`WATCHERS_POLL`]; a
/// failing sink is logged once per run of failures.
fn feed(mut sink: Box<dyn Sink>, rx: &Receiver<Msg>, seen: &AtomicU32) {
    let mut failing = false;
    loop {
        let msg = rx.recv_timeout(WATCHERS_POLL);
        let count = sink.watchers().unwrap_or(WATCHERS_UNKNOWN);
        seen.store(count, Ordering::Relaxed);
        let msg = match msg {
            Ok(msg) => msg,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        let r = match msg {
            Msg::Frame(frame) => {
                let r = sink.write(&frame);
                if r.is_ok() && tracing::enabled!(target: AGE_LOG, tracing::Level::TRACE) {
                    let age_us = monotonic_now_us().saturating_sub(frame.output.timestamp_us);
                    tracing::trace!(
                        target: AGE_LOG,
                        mode = %frame.mode.name(),
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
}

impl Output {
    pub fn spawn(sink: Box<dyn Sink>) -> std::io::Result<Self> {
        Self::spawn_set(SinkSet {
            primary: sink,
            also: Vec::new(),
        })
    }

    /// One thread per sink of `set`.
    pub fn spawn_set(set: SinkSet) -> std::io::Result<Self> {
        let info = set.primary.info();
        let also = set.also.iter().map(|s| s.info()).collect();
        let lanes = std::iter::once(set.primary)
            .chain(set.also)
            .map(Lane::spawn)
            .collect::<std::io::Result<_>>()?;
        Ok(Self { lanes, info, also })
    }

    /// The primary sink's description (the D-Bus sink properties).
    pub fn info(&self) -> &SinkInfo {
        &self.info
    }

    /// The sinks fed beside the primary one.
    pub fn also(&self) -> &[SinkInfo] {
        &self.also
    }

    /// Frames not shown because an output was busy: the most any one sink
    /// missed.
    pub fn dropped(&self) -> u64 {
        self.lanes
            .iter()
            .map(|l| l.queue.dropped())
            .max()
            .unwrap_or(0)
    }

    /// Readers watching the outputs, as the sinks last reported (refreshed
    /// with every frame and at least every 100 ms); `None` when a sink
    /// cannot tell (y4m, v4l2loopback 0.12.x).
    pub fn watchers(&self) -> Option<u32> {
        self.lanes
            .iter()
            .try_fold(0u32, |sum, l| match l.watchers.load(Ordering::Relaxed) {
                WATCHERS_UNKNOWN => None,
                n => Some(sum.saturating_add(n)),
            })
    }

    /// Queues a frame for every sink; never blocks.
    pub fn send(&self, frame: &Arc<OutFrame>) {
        self.send_all(Msg::Frame(frame.clone()));
    }

    /// Queues the "no signal" card stamped `timestamp_us`; never blocks.
    pub fn send_no_signal(&self, timestamp_us: u64) {
        self.send_all(Msg::NoSignal(timestamp_us));
    }

    fn send_all(&self, msg: Msg) {
        for l in &self.lanes {
            l.queue.offer(msg.clone());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Output;
    use crate::out_frame::OutFrame;
    use crate::sink::{Sink, SinkError, SinkInfo, SinkKindName, SinkSet};
    use sdi_core::display::DisplayMap;
    use sdi_core::mode::{ModeId, ModeOutput};
    use std::sync::{Arc, Mutex};
    use std::time::{Duration, Instant};

    /// (sequence, mode) of each frame a sink wrote.
    type Seen = Arc<Mutex<Vec<(u64, ModeId)>>>;

    /// A sink that records the sequence numbers and modes it was given,
    /// and can be held up (a stalled reader).
    struct Recording {
        kind: SinkKindName,
        seen: Seen,
        stall: Option<Arc<Mutex<()>>>,
        watchers: Option<u32>,
    }

    impl Sink for Recording {
        fn info(&self) -> SinkInfo {
            SinkInfo {
                kind: self.kind,
                device: self.kind.to_string(),
                format: String::new(),
                width: 0,
                height: 0,
            }
        }
        fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError> {
            if let Some(s) = &self.stall {
                drop(s.lock().unwrap());
            }
            self.seen
                .lock()
                .unwrap()
                .push((frame.output.sequence, frame.mode));
            Ok(())
        }
        fn write_no_signal(&mut self, _: u64) -> Result<(), SinkError> {
            Ok(())
        }
        fn watchers(&mut self) -> Option<u32> {
            self.watchers
        }
    }

    fn sink(
        kind: SinkKindName,
        stall: Option<Arc<Mutex<()>>>,
        watchers: Option<u32>,
    ) -> (Box<dyn Sink>, Seen) {
        let seen = Seen::default();
        let s = Recording {
            kind,
            seen: seen.clone(),
            stall,
            watchers,
        };
        (Box::new(s), seen)
    }

    fn frame(sequence: u64, mode: ModeId) -> Arc<OutFrame> {
        let mut o = ModeOutput::new(4, 2);
        o.sequence = sequence;
        Arc::new(OutFrame::new(o, mode, DisplayMap::default()))
    }

    fn wait_for(seen: &Seen, n: usize) -> Vec<(u64, ModeId)> {
        let t0 = Instant::now();
        while seen.lock().unwrap().len() < n && t0.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(2));
        }
        seen.lock().unwrap().clone()
    }

    /// Every sink of a set gets every frame with its mode, and one that
    /// stalls neither blocks the sender nor holds up the other sink; its
    /// missed frames are counted as dropped.
    #[test]
    fn each_sink_gets_the_frames_at_its_own_pace() {
        let stall = Arc::new(Mutex::new(()));
        let held = stall.lock().unwrap();
        let (loopback, _) = sink(SinkKindName::Loopback, Some(stall.clone()), Some(1));
        let (camera, camera_seen) = sink(SinkKindName::Pipewire, None, Some(2));
        let out = Output::spawn_set(SinkSet {
            primary: loopback,
            also: vec![camera],
        })
        .unwrap();
        assert_eq!(out.info().kind, SinkKindName::Loopback);
        assert_eq!(out.also().len(), 1);
        let t0 = Instant::now();
        for seq in 1..=20 {
            out.send(&frame(seq, ModeId::DepthEdge));
            // Let the free sink take each frame before the next.
            let _ = wait_for(&camera_seen, seq as usize);
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "the sender waited");
        let got = wait_for(&camera_seen, 20);
        let want: Vec<_> = (1..=20).map(|s| (s, ModeId::DepthEdge)).collect();
        assert_eq!(got, want, "the free sink missed frames");
        assert!(out.dropped() >= 16, "dropped {}", out.dropped());
        drop(held);
        let t0 = Instant::now();
        while out.watchers() != Some(3) && t0.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(out.watchers(), Some(3), "watchers of both sinks");
    }

    /// A sink that cannot count its readers makes the set's count unknown
    /// (the lights then assume someone watches).
    #[test]
    fn watchers_unknown_when_one_sink_cannot_tell() {
        let (a, _) = sink(SinkKindName::Loopback, None, None);
        let (b, _) = sink(SinkKindName::Pipewire, None, Some(1));
        let out = Output::spawn_set(SinkSet {
            primary: a,
            also: vec![b],
        })
        .unwrap();
        std::thread::sleep(Duration::from_millis(300));
        assert_eq!(out.watchers(), None);
    }
}
