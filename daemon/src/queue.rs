//! The one bounded queue between the frame loop and a consumer's thread
//! (each sink, each frame stream, the recorder): a fixed capacity, a send
//! that never blocks and counts what did not fit, and a thread that is
//! never waited for (it may be stuck in a write to a stalled reader).
//! std's `sync_channel` is the queue; this adds the thread, the counter
//! and the rule, written once instead of once per consumer.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

/// What became of an item offered to a [`Bounded`] queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Offer {
    Queued,
    /// The queue was full: dropped and counted.
    Dropped,
    /// The consumer's thread has ended (or the queue was closed).
    Gone,
}

/// A bounded queue feeding one consumer thread.
pub struct Bounded<T> {
    tx: Option<SyncSender<T>>,
    dropped: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl<T: Send + 'static> Bounded<T> {
    /// Starts thread `name` running `consume` on the queue's receiving end;
    /// it ends when `consume` returns (normally once the queue is closed
    /// and drained: `recv` fails).
    pub fn spawn(
        name: &str,
        capacity: usize,
        consume: impl FnOnce(Receiver<T>) + Send + 'static,
    ) -> std::io::Result<Self> {
        Self::spawn_counting(name, capacity, Arc::default(), consume)
    }

    /// [`Bounded::spawn`], counting drops in `dropped` (shared with the
    /// consumer, which reports it: the recorder's end record, a stream's
    /// headers).
    pub fn spawn_counting(
        name: &str,
        capacity: usize,
        dropped: Arc<AtomicU64>,
        consume: impl FnOnce(Receiver<T>) + Send + 'static,
    ) -> std::io::Result<Self> {
        let (tx, rx) = sync_channel(capacity);
        let thread = std::thread::Builder::new()
            .name(name.to_owned())
            .spawn(move || consume(rx))?;
        Ok(Self {
            tx: Some(tx),
            dropped,
            thread: Some(thread),
        })
    }
}

impl<T> Bounded<T> {
    /// Queues `item` if there is room; never blocks. A full queue drops it
    /// and counts the drop.
    pub fn offer(&self, item: T) -> Offer {
        let Some(tx) = &self.tx else {
            return Offer::Gone;
        };
        match tx.try_send(item) {
            Ok(()) => Offer::Queued,
            Err(TrySendError::Full(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
                Offer::Dropped
            }
            Err(TrySendError::Disconnected(_)) => Offer::Gone,
        }
    }

    /// Counts an item that was not offered (the consumer refused it before
    /// the queue saw it).
    pub fn count_drop(&self) {
        self.dropped.fetch_add(1, Ordering::Relaxed);
    }

    /// Items dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Closes the queue: the consumer drains what is queued, then its
    /// `recv` fails. Offers after this are [`Offer::Gone`].
    pub fn close(&mut self) {
        self.tx = None;
    }
}

impl<T> Drop for Bounded<T> {
    fn drop(&mut self) {
        self.close();
        // The thread may be blocked in a write to a stalled reader: it is
        // joined only if it has ended already, never waited for.
        if let Some(t) = self.thread.take() {
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;
    use std::time::Duration;

    /// A consumer held up fills the queue: later offers are dropped and
    /// counted, none blocks; once it goes on it gets what was queued, in
    /// order; after it ended, offers say so.
    #[test]
    fn a_stalled_consumer_costs_drops_never_a_wait() {
        let gate = Arc::new(Mutex::new(()));
        let held = gate.lock().unwrap();
        let got = Arc::new(Mutex::new(Vec::new()));
        let (g, seen) = (gate.clone(), got.clone());
        let mut q = Bounded::spawn("test-queue", 2, move |rx: Receiver<u32>| {
            while let Ok(v) = rx.recv() {
                drop(g.lock().unwrap());
                seen.lock().unwrap().push(v);
                if v == 99 {
                    return;
                }
            }
        })
        .unwrap();
        // The first item may already be taken (and held at the gate).
        let offers: Vec<Offer> = (1..=10).map(|v| q.offer(v)).collect();
        let queued = offers.iter().filter(|&&o| o == Offer::Queued).count();
        assert!((2..=3).contains(&queued), "{offers:?}");
        assert_eq!(q.dropped(), 10 - queued as u64);
        drop(held);
        let t0 = std::time::Instant::now();
        while got.lock().unwrap().len() < queued {
            assert!(t0.elapsed() < Duration::from_secs(20));
            std::thread::sleep(Duration::from_millis(2));
        }
        assert_eq!(
            *got.lock().unwrap(),
            (1..=queued as u32).collect::<Vec<_>>()
        );
        q.offer(99);
        while q.offer(0) != Offer::Gone {
            assert!(t0.elapsed() < Duration::from_secs(20));
            std::thread::sleep(Duration::from_millis(2));
        }
        q.close();
        assert_eq!(q.offer(1), Offer::Gone);
    }
}
