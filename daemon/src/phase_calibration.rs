//! The phase calibration job: frames with LS1 alone lit, their quads'
//! (I, Q) summed, and the axis of LS1 - LS2 fitted from them
//! (`sdi_core::quad_phase::fit_axis`, eq. pixeleff with a delay on the LED
//! path).
//!
//! The job asks for LS1 alone; `[lights]` drives that when a rig is
//! configured, otherwise the person calibrating has covered LS2. Only the
//! board's frames count: a frame without sums (a stand-in's) is skipped.

use sdi_core::modulation::{Illumination, SourceDrive};
use sdi_core::quad_phase::{LitSource, PhaseAxis, PhaseError, PhaseSums};
use sdi_core::Frame;

use crate::backend::CaptureSettings;
use crate::job::{Job, Step};

/// Smallest mean amplitude of the lit source trusted, DN (quad 0's scale):
/// a few times the read noise of one quad (about 4 DN on the OPT8241).
pub const MIN_AMPLITUDE_DN: f64 = 10.0;

/// Settled frames left out before summing: frames the board had already
/// queued (transfers in flight) may still carry the light before the change.
pub const FRAMES_IN_FLIGHT: u32 = 4;

/// A fitted phase axis and what it rests on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseFit {
    pub axis: PhaseAxis,
    /// Mean amplitude of LS1's light per pixel and frame, DN.
    pub amplitude_dn: f64,
    /// |sum of (I, Q)| / sum of |(I, Q)| over the pixels.
    pub coherence: f64,
    /// Frames summed.
    pub frames: u32,
}

pub struct PhaseJob {
    wanted: u32,
    skipped: u32,
    frames: u32,
    sums: PhaseSums,
    /// The sums of the frame about to be processed ([`PhaseJob::offer`]).
    offered: Option<PhaseSums>,
}

impl PhaseJob {
    /// Sums `frames` (at least 1) frames.
    pub fn new(frames: u32) -> Self {
        Self {
            wanted: frames.max(1),
            skipped: 0,
            frames: 0,
            sums: PhaseSums::default(),
            offered: None,
        }
    }

    /// The (I, Q) sums of the frame that [`Job::process`] gets next.
    pub fn offer(&mut self, sums: Option<PhaseSums>) {
        self.offered = sums;
    }
}

impl Job for PhaseJob {
    type Output = Result<PhaseFit, PhaseError>;

    fn prepare(&mut self) -> Option<CaptureSettings> {
        None
    }

    /// LS1 by f, LS2 off.
    fn illumination(&self, carrier_hz: f64) -> Illumination {
        Illumination {
            ls1: SourceDrive::Modulated,
            ls2: SourceDrive::Off,
            ..Illumination::snapshot(carrier_hz)
        }
    }

    fn process(&mut self, _frame: &Frame) -> Step<Self::Output> {
        let Some(sums) = self.offered.take() else {
            return Step::Continue;
        };
        if self.skipped < FRAMES_IN_FLIGHT {
            self.skipped += 1;
            return Step::Continue;
        }
        self.sums.add(&sums);
        self.frames += 1;
        if self.frames < self.wanted {
            return Step::Continue;
        }
        let fit = self
            .sums
            .fit(LitSource::Ls1, MIN_AMPLITUDE_DN)
            .map(|axis| PhaseFit {
                axis,
                amplitude_dn: self.sums.amplitude_dn(),
                coherence: self.sums.coherence(),
                frames: self.frames,
            });
        Step::Done(fit)
    }

    fn restore(&self) -> Option<CaptureSettings> {
        None
    }

    fn progress(&self) -> u32 {
        self.frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_core::quad_phase::QuadBasis;

    fn sums_for(d: f32, delay_rad: f32) -> PhaseSums {
        let b = QuadBasis::new(4).unwrap();
        let q: Vec<f32> = (0..4)
            .map(|k| d * (std::f32::consts::FRAC_PI_2 * k as f32 - delay_rad).cos())
            .collect();
        let (i, qq) = b.in_phase_quadrature(&q);
        let mut s = PhaseSums::new(4);
        s.push(i, qq);
        s
    }

    #[test]
    fn skips_the_frames_in_flight_then_fits_ls1() {
        let mut job = PhaseJob::new(2);
        let f = Frame::new(1, 1);
        let ill = job.illumination(12e6);
        assert_eq!(
            (ill.ls1, ill.ls2),
            (SourceDrive::Modulated, SourceDrive::Off)
        );
        // frames without sums (a stand-in's) are not counted
        assert!(matches!(job.process(&f), Step::Continue));
        for _ in 0..FRAMES_IN_FLIGHT {
            // stale light, the opposite way: left out
            job.offer(Some(sums_for(-500.0, 1.0)));
            assert!(matches!(job.process(&f), Step::Continue));
        }
        job.offer(Some(sums_for(100.0, 1.0)));
        assert!(matches!(job.process(&f), Step::Continue));
        job.offer(Some(sums_for(100.0, 1.0)));
        let Step::Done(Ok(fit)) = job.process(&f) else {
            panic!("two frames make a fit")
        };
        assert!((fit.axis.angle_rad - 1.0).abs() < 1e-4, "{fit:?}");
        assert!((fit.amplitude_dn - 100.0).abs() < 1e-3, "{fit:?}");
        assert_eq!(fit.frames, 2);
    }

    #[test]
    fn a_dark_scene_is_too_dim() {
        let mut job = PhaseJob::new(1);
        let f = Frame::new(1, 1);
        for _ in 0..=FRAMES_IN_FLIGHT {
            job.offer(Some(sums_for(2.0, 0.0)));
            if let Step::Done(r) = job.process(&f) {
                assert!(matches!(r, Err(PhaseError::TooDim { .. })), "{r:?}");
                return;
            }
        }
        panic!("no result");
    }
}
