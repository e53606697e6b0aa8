//! A fair share of the daemon for every caller. zbus serves each method
//! call in its own task, so 10,000 calls queued by one connection would all
//! wait for the change lock and the frame loop ahead of another client's
//! call. Here each connection (the message's unique sender name) gets at
//! most [`CALLS_PER_SENDER`] calls served at once; the rest wait in that
//! sender's own queue, so another client waits behind at most that many.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use zbus::message::Header;

/// Calls of one connection served at once (each is answered by the next
/// frame, so this bounds what one client puts ahead of everyone else).
pub const CALLS_PER_SENDER: usize = 16;

/// Per-sender queues, dropped when a sender has nothing waiting or running.
#[derive(Debug, Default)]
pub struct Fairness {
    senders: Mutex<HashMap<String, Arc<Semaphore>>>,
}

/// One call's turn; the next call of the same sender goes when it is dropped.
pub struct Turn<'a> {
    permit: Option<OwnedSemaphorePermit>,
    sender: String,
    fairness: &'a Fairness,
}

impl Fairness {
    fn queue(&self, sender: &str) -> Arc<Semaphore> {
        let mut map = match self.senders.lock() {
            Ok(m) => m,
            Err(p) => p.into_inner(),
        };
        map.entry(sender.to_owned())
            .or_insert_with(|| Arc::new(Semaphore::new(CALLS_PER_SENDER)))
            .clone()
    }

    /// Waits for the calling connection's turn (FIFO within a sender).
    pub async fn turn(&self, hdr: &Header<'_>) -> Turn<'_> {
        let sender = hdr.sender().map(|s| s.to_string()).unwrap_or_default();
        self.turn_of(sender).await
    }

    async fn turn_of(&self, sender: String) -> Turn<'_> {
        // The semaphore is never closed, so acquiring cannot fail; were it
        // to, the call would simply go ahead unqueued.
        let permit = self.queue(&sender).acquire_owned().await.ok();
        Turn {
            permit,
            sender,
            fairness: self,
        }
    }

    /// Senders with a call waiting or running.
    pub fn senders(&self) -> usize {
        self.senders.lock().map_or(0, |m| m.len())
    }
}

impl Drop for Turn<'_> {
    fn drop(&mut self) {
        drop(self.permit.take());
        let mut map = match self.fairness.senders.lock() {
            Ok(m) => m,
            Err(p) => p.into_inner(),
        };
        // Only the map holds it: nothing of this sender waits or runs.
        if map
            .get(&self.sender)
            .is_some_and(|s| Arc::strong_count(s) == 1)
        {
            map.remove(&self.sender);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn a_flooding_sender_does_not_delay_another() {
        let fair = Arc::new(Fairness::default());
        let mut held = Vec::new();
        for _ in 0..CALLS_PER_SENDER {
            held.push(fair.turn_of(":1.1".into()).await);
        }
        // The flooder's next call waits ...
        let f2 = fair.clone();
        let waiting = tokio::spawn(async move {
            let _t = f2.turn_of(":1.1".into()).await;
        });
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert!(!waiting.is_finished());
        // ... another sender goes at once.
        let other = tokio::time::timeout(Duration::from_secs(1), fair.turn_of(":1.2".into()))
            .await
            .unwrap();
        drop(other);
        drop(held);
        waiting.await.unwrap();
        assert_eq!(fair.senders(), 0, "queues of idle senders are dropped");
    }
}
