//! The light sources: on only while someone needs the picture, driven as
//! the running job or the mode asks.

use sdi_core::modulation::Illumination;

use super::FrameLoop;

/// Whether the light sources must be on: someone watches the output (or
/// the sink cannot tell: v4l2loopback 0.12.x, y4m), a recording runs, or a
/// snapshot waits. Dark calibration runs dark anyway.
pub fn lights_needed(watchers: Option<u32>, recording: bool, snapshot_pending: bool) -> bool {
    watchers != Some(0) || recording || snapshot_pending
}

impl FrameLoop {
    /// Whether the mode's light sources are to be on for the next capture
    /// (never during a job: it drives them itself).
    pub(super) fn lights_wanted(&mut self) -> bool {
        self.job.is_none()
            && lights_needed(
                self.fanout.watchers(),
                self.recorder.is_some(),
                !self.pending_snapshots.is_empty(),
            )
    }

    /// How the sources are driven for the next capture: as the job asks,
    /// as the mode asks when `lit`, else dark.
    pub(super) fn illumination(&self, lit: bool) -> Illumination {
        let carrier_hz = self.backend.settings().modulation_hz;
        if let Some(job) = &self.job {
            job.illumination(carrier_hz)
        } else if lit {
            // Numbered as the frame will be: the two-shot pipeline pairs by it.
            self.mode.illumination(self.sequence + 1, carrier_hz)
        } else {
            Illumination::dark(carrier_hz)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::lights_needed;

    #[test]
    fn lights_only_while_someone_needs_them() {
        // nobody watches, nothing records or waits: dark
        assert!(!lights_needed(Some(0), false, false));
        // a reader, a recording or a pending snapshot each turn them on
        assert!(lights_needed(Some(1), false, false));
        assert!(lights_needed(Some(0), true, false));
        assert!(lights_needed(Some(0), false, true));
        // the sink cannot tell (v4l2loopback 0.12.x, y4m): on
        assert!(lights_needed(None, false, false));
    }
}
