//! The job machinery: one job at a time holds the camera, its progress is
//! published, and its caller's departure, `Cancel` or its deadline end it.

use std::time::Duration;

use tokio::sync::oneshot;
use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::Connection;

use super::caller::caller_uid;
use super::Camera;
use crate::dbus::errors::{frame_loop_stopped, SdiError};
use crate::dbus::job_slot::{CancelCause, JobKind, JobTicket, MAX_JOB_SECONDS};
use crate::dbus::peers::{self, Departure};
use crate::frame_loop::{Command, JobError, Reply};

/// Largest number of frames one dark-frame or calibration call may average.
pub const MAX_AVERAGE_FRAMES: u32 = 10_000;

/// A job in progress: the slot's ticket, the caller's departure (None:
/// the call names no sender), the deadline.
pub(super) struct RunningJob<'a> {
    ticket: JobTicket<'a>,
    caller_left: Option<Departure>,
    deadline: tokio::time::Instant,
    bound: Duration,
}

/// Resolves when the job's caller has left the bus; never without a caller.
async fn caller_left(departure: &mut Option<Departure>) {
    match departure {
        Some(d) => d.await,
        None => std::future::pending().await,
    }
}

/// How often a running job's progress is published (`Job`).
const JOB_PROGRESS_PERIOD: Duration = Duration::from_millis(250);

/// Jobs: one at a time, taken once for all their steps, ended by their
/// caller's departure, `Cancel` or their deadline.
impl Camera {
    /// Checks `frames` against `[min, MAX_AVERAGE_FRAMES]`.
    pub(super) fn check_frames(frames: u32, min: u32) -> Result<(), SdiError> {
        if frames < min || frames > MAX_AVERAGE_FRAMES {
            return Err(SdiError::OutOfRange(format!(
                "frames = {frames} is out of range: allowed [{min}, {MAX_AVERAGE_FRAMES}]"
            )));
        }
        Ok(())
    }

    /// Takes the camera for a job of `total` frames (`captures`: with the
    /// captures its settings need to settle): refused while another job or a
    /// recording runs, or when it would take longer than [`MAX_JOB_SECONDS`]
    /// at the current frame rate.
    pub(super) async fn begin_job(
        &self,
        kind: JobKind,
        total: u32,
        captures: u32,
        hdr: &Header<'_>,
        conn: &Connection,
    ) -> Result<RunningJob<'_>, SdiError> {
        self.require_device()?;
        let rate_hz = self.state().capture.frame_rate_hz.max(1e-3);
        let estimate_s = f64::from(captures) / rate_hz;
        if estimate_s > MAX_JOB_SECONDS {
            return Err(SdiError::OutOfRange(format!(
                "the {} takes {captures} frames, {estimate_s:.0} s at {rate_hz} Hz: a job may take \
                 at most {MAX_JOB_SECONDS:.0} s (fewer frames, or a higher frame rate)",
                kind.name()
            )));
        }
        let caller = peers::caller(hdr);
        let owner = caller.as_ref().map_or_else(String::new, |c| c.to_string());
        let uid = caller_uid(conn, hdr).await;
        let now = *self.job_progress.borrow();
        let ticket = self.jobs.begin(kind, total, &owner, uid, now)?;
        {
            // After any setting change or recording start under way; those
            // that come later see the job.
            let _changes = self.change_lock.lock().await;
            if let Some(p) = self.state().recording {
                return Err(SdiError::Busy(format!(
                    "recording to {} runs: a {} would leave a gap in it; stop the recording first",
                    p.display(),
                    kind.name()
                )));
            }
        }
        // Watched in a task of its own: `job_step` awaits sends in its
        // select's branch bodies (see `Departure`).
        let caller_left = caller.map(|c| Departure::watch(conn.clone(), c));
        // Twice the estimate and 10 s: room for a source slower than its rate.
        let bound = Duration::from_secs_f64(2.0 * estimate_s + 10.0);
        Ok(RunningJob {
            ticket,
            caller_left,
            deadline: tokio::time::Instant::now() + bound,
            bound,
        })
    }

    /// Runs one step of `job` in the frame loop, publishing its progress;
    /// cancels it (and answers `Cancelled`) when its caller leaves the bus,
    /// someone calls `Cancel` or the deadline passes.
    pub(super) async fn job_step<T>(
        &self,
        job: &mut RunningJob<'_>,
        emitter: &SignalEmitter<'_>,
        make: impl FnOnce(Reply<Result<T, JobError>>) -> Command,
    ) -> Result<Result<T, JobError>, SdiError> {
        let kind = job.ticket.kind;
        let cancelled =
            |cause: CancelCause| SdiError::Cancelled(format!("the {} was {cause}", kind.name()));
        if let Some(cause) = job.ticket.cancel_requested() {
            return Err(cancelled(cause));
        }
        let (tx, mut rx) = oneshot::channel();
        self.send(make(tx))?;
        let mut tick = tokio::time::interval(JOB_PROGRESS_PERIOD);
        let cause = loop {
            tokio::select! {
                r = &mut rx => return r.map_err(frame_loop_stopped),
                c = job.ticket.cancelled() => break c,
                () = caller_left(&mut job.caller_left) => break CancelCause::CallerLeft,
                () = tokio::time::sleep_until(job.deadline) => break CancelCause::TimedOut(job.bound),
                _ = tick.tick() => {
                    job.ticket.progress.stage(*self.job_progress.borrow());
                    let _ = self.job_changed(emitter).await;
                }
            }
        };
        tracing::info!(job = kind.name(), "{cause}");
        self.send(Command::CancelJob)?;
        match rx.await.map_err(frame_loop_stopped)? {
            Err(JobError::Cancelled) => Err(cancelled(cause)),
            // It finished before the cancel reached it.
            done => Ok(done),
        }
    }

    /// Ends a step: the next step's frames count on from its `frames`.
    pub(super) fn job_step_done(&self, job: &RunningJob<'_>, frames: u32) {
        job.ticket
            .progress
            .next_stage(frames, *self.job_progress.borrow());
    }

    /// Cancels the running job for the caller; returns its name, "" when none runs.
    pub(super) async fn cancel_job(
        &self,
        hdr: &Header<'_>,
        conn: &Connection,
    ) -> Result<String, SdiError> {
        let caller = peers::caller(hdr).map_or_else(String::new, |c| c.to_string());
        let uid = caller_uid(conn, hdr).await;
        let kind = self.jobs.cancel(&caller, uid)?;
        if let Some(k) = kind {
            tracing::info!(job = k.name(), by = caller, "cancel asked");
        }
        Ok(kind.map_or_else(String::new, |k| k.name().to_owned()))
    }
}
