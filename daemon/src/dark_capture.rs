//! The dark-frame capture job: N frames with both sources off, averaged by
//! core's [`DarkAccumulator`] (section 4, measurement procedure).

use sdi_core::dark_frame::{DarkAccumulator, DarkStats};
use sdi_core::modulation::Illumination;
use sdi_core::{Frame, Image};

use crate::backend::CaptureSettings;
use crate::job::{Job, Step};

/// What a finished dark capture yields.
#[derive(Debug, Clone, PartialEq)]
pub struct DarkCapture {
    /// Mean dark frame, DN (pixels never valid: 0).
    pub dark_dn: Image<f32>,
    pub stats: DarkStats,
}

/// Why a dark capture produced nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("every dark sample was saturated or not finite")]
pub struct NoUsablePixels;

pub struct DarkJob {
    wanted: u32,
    acc: DarkAccumulator,
}

impl DarkJob {
    /// Averages `frames` (at least 1) frames of `width` x `height`.
    pub fn new(frames: u32, width: usize, height: usize) -> Self {
        Self {
            wanted: frames.max(1),
            acc: DarkAccumulator::new(width, height),
        }
    }
}

impl Job for DarkJob {
    type Output = Result<DarkCapture, NoUsablePixels>;

    fn prepare(&mut self) -> Option<CaptureSettings> {
        None
    }

    fn illumination(&self, carrier_hz: f64) -> Illumination {
        Illumination::dark(carrier_hz)
    }

    fn process(&mut self, frame: &Frame) -> Step<Self::Output> {
        // A frame of another size (the source changed under us) is not counted.
        if self.acc.push(frame).is_err() || self.acc.frames() < self.wanted {
            return Step::Continue;
        }
        let capture = self
            .acc
            .stats()
            .zip(self.acc.mean_dn())
            .map(|(stats, dark_dn)| DarkCapture { dark_dn, stats })
            .ok_or(NoUsablePixels);
        Step::Done(capture)
    }

    fn restore(&self) -> Option<CaptureSettings> {
        None
    }

    fn progress(&self) -> u32 {
        self.acc.frames()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averages_the_wanted_frames() {
        let mut job = DarkJob::new(2, 2, 1);
        let mut f = Frame::new(2, 1);
        f.dn.data = vec![10.0, 20.0];
        assert!(matches!(job.process(&f), Step::Continue));
        // another size is not counted
        assert!(matches!(job.process(&Frame::new(3, 1)), Step::Continue));
        f.dn.data = vec![12.0, 22.0];
        let Step::Done(Ok(c)) = job.process(&f) else {
            panic!("two frames make a dark frame")
        };
        assert_eq!(c.dark_dn.data, vec![11.0, 21.0]);
        assert_eq!(c.stats.frames, 2);
        assert_eq!(c.stats.read_noise_variance_dn2, 2.0);
    }

    #[test]
    fn nothing_usable_is_an_error() {
        let mut job = DarkJob::new(1, 1, 1);
        let mut f = Frame::new(1, 1);
        f.dn.data = vec![f32::NAN];
        assert!(matches!(job.process(&f), Step::Done(Err(NoUsablePixels))));
    }
}
