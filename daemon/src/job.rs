//! Jobs: what the frame loop runs instead of the mode pipeline for a while
//! (a dark-frame capture, the photon-transfer calibration). One model for
//! all of them: prepare (capture settings to apply first), then frames in,
//! one [`Step`] out per frame, until the job is done and the settings it
//! changed are put back.

use sdi_core::modulation::Illumination;
use sdi_core::Frame;

use crate::backend::{Backend, BackendError, CaptureSettings};

/// What the frame loop does after feeding a job a frame.
#[derive(Debug)]
pub enum Step<T> {
    /// Keep capturing with the same settings.
    Continue,
    /// Apply these settings before the next frame.
    Configure(CaptureSettings),
    /// Finished with this result.
    Done(T),
}

/// A job the frame loop runs frame by frame.
pub trait Job {
    type Output;
    /// Capture settings to apply before the first frame (`None`: keep the current ones).
    fn prepare(&mut self) -> Option<CaptureSettings>;
    /// How the light sources are driven while the job runs.
    fn illumination(&self, carrier_hz: f64) -> Illumination;
    /// Feeds one frame captured wholly under the job's current settings.
    fn process(&mut self, frame: &Frame) -> Step<Self::Output>;
    /// Settings to put back when the job ends (`None`: it changed none).
    fn restore(&self) -> Option<CaptureSettings>;
    /// Frames it has taken so far (the `Job` property's count).
    fn progress(&self) -> u32;
}

/// A setting that takes effect one frame late: the board latches exposure
/// and light drive at a frame boundary, so the first capture after a change
/// may still carry the old value. The one place this rule lives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Settling {
    captures_since_change: u32,
}

impl Settling {
    /// Captures after a change until one is wholly under the new value.
    const CAPTURES: u32 = 2;

    /// Nothing changed: the next capture counts.
    pub fn settled() -> Self {
        Self {
            captures_since_change: Self::CAPTURES,
        }
    }

    /// Just changed: the next capture may still carry the old value.
    pub fn changed() -> Self {
        Self {
            captures_since_change: 0,
        }
    }

    /// Notes a change.
    pub fn change(&mut self) {
        *self = Self::changed();
    }

    /// Notes one capture; true when it was taken wholly under the current value.
    pub fn capture(&mut self) -> bool {
        self.captures_since_change = self.captures_since_change.saturating_add(1);
        self.is_settled()
    }

    /// Whether the last capture was taken wholly under the current value.
    pub fn is_settled(&self) -> bool {
        self.captures_since_change >= Self::CAPTURES
    }
}

/// A job in progress: the job and whether its settings have settled.
pub struct Running<J> {
    job: J,
    settling: Settling,
}

impl<J: Job> Running<J> {
    /// Applies the job's settings; a backend that refuses them fails the start.
    pub fn start(mut job: J, backend: &mut dyn Backend) -> Result<Self, BackendError> {
        let settling = match job.prepare() {
            Some(settings) => {
                backend.configure(&settings)?;
                Settling::changed()
            }
            None => Settling::settled(),
        };
        Ok(Self { job, settling })
    }

    pub fn illumination(&self, carrier_hz: f64) -> Illumination {
        self.job.illumination(carrier_hz)
    }

    /// Frames the job has taken so far.
    pub fn progress(&self) -> u32 {
        self.job.progress()
    }

    /// The job, to hand it what a capture yields besides the frame.
    pub fn job_mut(&mut self) -> &mut J {
        &mut self.job
    }

    /// Feeds a captured frame (skipped while the settings settle); the
    /// job's output once it is done.
    pub fn feed(
        &mut self,
        frame: &Frame,
        backend: &mut dyn Backend,
    ) -> Result<Option<J::Output>, BackendError> {
        if !self.settling.capture() {
            return Ok(None);
        }
        match self.job.process(frame) {
            Step::Continue => Ok(None),
            Step::Configure(settings) => {
                backend.configure(&settings)?;
                self.settling.change();
                Ok(None)
            }
            Step::Done(out) => Ok(Some(out)),
        }
    }

    /// Puts back the settings the job changed.
    pub fn end(self, backend: &mut dyn Backend) -> Result<(), BackendError> {
        match self.job.restore() {
            Some(settings) => backend.configure(&settings),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Settling;

    #[test]
    fn a_change_skips_one_capture() {
        let mut s = Settling::settled();
        assert!(s.is_settled());
        assert!(s.capture());
        s.change();
        assert!(!s.is_settled());
        assert!(!s.capture(), "first capture after the change");
        assert!(s.capture());
        assert!(s.capture());
    }

    #[test]
    fn changed_starts_unsettled() {
        let mut s = Settling::changed();
        assert!(!s.capture());
        assert!(s.capture());
    }
}
