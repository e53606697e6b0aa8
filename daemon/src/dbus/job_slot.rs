//! Who holds the camera for a job (a dark frame, a calibration, a phase
//! calibration), taken once for the whole job: one job at a time, named in
//! every refusal; its caller, who may cancel it; how far it got.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::watch;

use super::errors::SdiError;
use crate::frame_loop::JobProgress;

/// Longest a job may take: one whose frames would take longer at the
/// current frame rate is refused before it starts.
pub const MAX_JOB_SECONDS: f64 = 600.0;

/// The jobs a caller can start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobKind {
    DarkFrame,
    Calibration,
    PhaseCalibration,
}

impl JobKind {
    /// The name the `Job` property, `Cancel` and the refusals give it.
    pub fn name(self) -> &'static str {
        match self {
            JobKind::DarkFrame => "dark frame",
            JobKind::Calibration => "calibration",
            JobKind::PhaseCalibration => "phase calibration",
        }
    }
}

/// Why a job was cancelled (the message of `org.sdi.Error.Cancelled`).
#[derive(Debug, Clone, PartialEq)]
pub enum CancelCause {
    /// `Cancel` by this connection.
    Requested(String),
    /// The caller left the bus.
    CallerLeft,
    /// Still running at its deadline.
    TimedOut(Duration),
}

impl std::fmt::Display for CancelCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CancelCause::Requested(by) => write!(f, "cancelled by {by}"),
            CancelCause::CallerLeft => write!(f, "cancelled: its caller left the bus"),
            CancelCause::TimedOut(d) => {
                write!(f, "cancelled: still running after {} s", d.as_secs())
            }
        }
    }
}

/// The running job as the slot holds it.
struct Holder {
    id: u64,
    kind: JobKind,
    owner: String,
    owner_uid: Option<u32>,
    cancel: watch::Sender<Option<CancelCause>>,
    progress: Arc<Progress>,
}

/// Frames a job has taken, of how many, from the frame loop's count of
/// each step ([`crate::frame_loop::JobProgress`]).
#[derive(Debug, Default)]
pub struct Progress {
    /// Frames of the steps finished before the current one.
    offset: AtomicU32,
    /// The frame loop's number of a job that is not the current step (the
    /// one before it): its count is not this step's.
    stale: AtomicU64,
    /// Most frames reported so far (never goes back).
    done: AtomicU32,
    total: AtomicU32,
}

impl Progress {
    /// Notes the frame loop's count of the current step.
    pub fn stage(&self, p: JobProgress) {
        if p.job == self.stale.load(Ordering::Relaxed) {
            return;
        }
        let done = self.offset.load(Ordering::Relaxed).saturating_add(p.frames);
        let total = self.total.load(Ordering::Relaxed);
        self.done.fetch_max(done.min(total), Ordering::Relaxed);
    }

    /// A step of `frames` is done (`now`: the frame loop's progress as it
    /// ended): the next one's frames count from here.
    pub fn next_stage(&self, frames: u32, now: JobProgress) {
        self.stale.store(now.job, Ordering::Relaxed);
        self.offset.fetch_add(frames, Ordering::Relaxed);
        self.stage(JobProgress {
            job: u64::MAX,
            frames: 0,
        });
    }

    /// (frames done, frames in all).
    pub fn get(&self) -> (u32, u32) {
        (
            self.done.load(Ordering::Relaxed),
            self.total.load(Ordering::Relaxed),
        )
    }
}

/// One job at a time.
#[derive(Default)]
pub struct JobSlot {
    current: Mutex<Option<Holder>>,
    next_id: AtomicU64,
}

/// The caller's hold on the slot; dropping it frees the slot.
pub struct JobTicket<'a> {
    slot: &'a JobSlot,
    id: u64,
    pub kind: JobKind,
    cancel: watch::Receiver<Option<CancelCause>>,
    pub progress: Arc<Progress>,
}

impl JobSlot {
    fn lock(&self) -> std::sync::MutexGuard<'_, Option<Holder>> {
        match self.current.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        }
    }

    /// Takes the slot for `kind` of `total_frames`, started by `owner`
    /// (`now`: the frame loop's progress before it starts); `Busy` naming
    /// the running job if one holds it.
    pub fn begin(
        &self,
        kind: JobKind,
        total_frames: u32,
        owner: &str,
        owner_uid: Option<u32>,
        now: JobProgress,
    ) -> Result<JobTicket<'_>, SdiError> {
        let mut cur = self.lock();
        if let Some(h) = cur.as_ref() {
            return Err(busy(h, &format!("a {} is refused", kind.name())));
        }
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let (cancel, rx) = watch::channel(None);
        let progress = Arc::new(Progress::default());
        progress.total.store(total_frames, Ordering::Relaxed);
        progress.stale.store(now.job, Ordering::Relaxed);
        *cur = Some(Holder {
            id,
            kind,
            owner: owner.to_owned(),
            owner_uid,
            cancel,
            progress: progress.clone(),
        });
        Ok(JobTicket {
            slot: self,
            id,
            kind,
            cancel: rx,
            progress,
        })
    }

    /// `Busy` naming the running job, saying that `refused` is; None when
    /// no job runs.
    pub fn busy(&self, refused: &str) -> Option<SdiError> {
        self.lock().as_ref().map(|h| busy(h, refused))
    }

    /// The running job: its name, frames done and in all.
    pub fn progress(&self) -> Option<(JobKind, u32, u32)> {
        self.lock().as_ref().map(|h| {
            let (done, total) = h.progress.get();
            (h.kind, done, total)
        })
    }

    /// Cancels the running job for `caller` (uid `caller_uid`): its own
    /// caller, a connection of the same user, or root may. The job's name,
    /// None when none runs.
    pub fn cancel(
        &self,
        caller: &str,
        caller_uid: Option<u32>,
    ) -> Result<Option<JobKind>, SdiError> {
        let cur = self.lock();
        let Some(h) = cur.as_ref() else {
            return Ok(None);
        };
        let same_user = caller_uid.is_some_and(|u| u == 0 || Some(u) == h.owner_uid);
        if caller != h.owner && !same_user {
            return Err(SdiError::ZBus(zbus::Error::from(
                zbus::fdo::Error::AccessDenied(format!(
                    "the {} belongs to another user: only its caller, that user or root may cancel it",
                    h.kind.name()
                )),
            )));
        }
        h.cancel
            .send_replace(Some(CancelCause::Requested(caller.to_owned())));
        Ok(Some(h.kind))
    }
}

fn busy(h: &Holder, refused: &str) -> SdiError {
    let (done, total) = h.progress.get();
    SdiError::Busy(format!(
        "a {} (frame {done} of {total}, started by {}) holds the camera: {refused} until it \
         ends or is cancelled (Cancel)",
        h.kind.name(),
        h.owner
    ))
}

impl JobTicket<'_> {
    /// Resolves when the job is to be cancelled, with why.
    pub async fn cancelled(&mut self) -> CancelCause {
        loop {
            if let Some(c) = self.cancel.borrow_and_update().clone() {
                return c;
            }
            if self.cancel.changed().await.is_err() {
                // The sender lives in the slot as long as this ticket.
                std::future::pending::<()>().await;
            }
        }
    }

    /// Whether a cancel was asked for (between a job's steps).
    pub fn cancel_requested(&self) -> Option<CancelCause> {
        self.cancel.borrow().clone()
    }
}

impl Drop for JobTicket<'_> {
    fn drop(&mut self) {
        let mut cur = self.slot.lock();
        if cur.as_ref().is_some_and(|h| h.id == self.id) {
            *cur = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_job_at_a_time_named_in_the_refusal() {
        let slot = JobSlot::default();
        let p = |job, frames| JobProgress { job, frames };
        let t = slot
            .begin(JobKind::Calibration, 60, ":1.5", Some(1000), p(3, 7))
            .unwrap();
        let Err(SdiError::Busy(m)) = slot.begin(JobKind::DarkFrame, 4, ":1.6", Some(1000), p(3, 7))
        else {
            panic!("a second job")
        };
        assert!(m.contains("calibration") && m.contains(":1.5"), "{m}");
        // The last job's count is not this one's.
        t.progress.stage(p(3, 7));
        assert_eq!(slot.progress(), Some((JobKind::Calibration, 0, 60)));
        t.progress.stage(p(4, 10));
        t.progress.next_stage(10, p(4, 10));
        t.progress.stage(p(4, 10));
        assert_eq!(slot.progress(), Some((JobKind::Calibration, 10, 60)));
        t.progress.stage(p(5, 2));
        assert_eq!(slot.progress(), Some((JobKind::Calibration, 12, 60)));
        drop(t);
        assert!(slot.busy("x").is_none());
        assert!(slot
            .begin(JobKind::DarkFrame, 4, ":1.6", None, p(5, 2))
            .is_ok());
    }

    #[tokio::test]
    async fn cancel_by_the_caller_or_its_user_only() {
        let slot = JobSlot::default();
        assert!(matches!(slot.cancel(":1.9", Some(1)), Ok(None)));
        let mut t = slot
            .begin(
                JobKind::DarkFrame,
                4,
                ":1.5",
                Some(1000),
                JobProgress::default(),
            )
            .unwrap();
        assert!(slot.cancel(":1.7", Some(1001)).is_err(), "another user");
        assert!(slot.cancel(":1.7", None).is_err(), "an unknown user");
        assert!(t.cancel_requested().is_none());
        assert_eq!(
            slot.cancel(":1.8", Some(1000)).unwrap(),
            Some(JobKind::DarkFrame)
        );
        assert_eq!(t.cancelled().await, CancelCause::Requested(":1.8".into()));
    }
}
