//! Frame sources behind one trait: the simulator, recordings, and the real
//! board. A backend delivers sensor frames; the frame loop paces those
//! without a frame clock of their own ([`pacer`]).

pub mod board;
pub mod opt8241;
pub mod pacer;
pub mod replay;
pub mod select;
pub mod sim;
pub mod status;

use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::quad_phase::{PhaseAxis, PhaseSums};
use sdi_core::sensor::{capture_range, SensorParams};
use sdi_core::{Frame, Image};

/// Capture settings a client may change at run time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureSettings {
    pub exposure_us: f64,
    pub frame_rate_hz: f64,
    pub modulation_hz: f64,
}

/// Closed ranges a backend accepts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub exposure_us: (f64, f64),
    pub frame_rate_hz: (f64, f64),
    pub modulation_hz: (f64, f64),
}

impl Limits {
    /// Broad physical limits of a two-well ToF sensor.
    /// The capture ranges of `sdi_core::sensor::capture_range`, the same the
    /// configuration and the command line accept.
    pub const DEFAULT: Limits = Limits {
        exposure_us: capture_range::EXPOSURE_US.bounds(),
        frame_rate_hz: capture_range::FRAME_RATE_HZ.bounds(),
        modulation_hz: capture_range::MODULATION_HZ.bounds(),
    };
}

/// What went wrong in a backend.
#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error("device unavailable: {0}")]
    Unavailable(String),
    #[error("{0}")]
    OutOfRange(String),
    #[error("end of recording")]
    EndOfStream,
    #[error("{0}")]
    Failed(String),
    /// No frame yet within one slice of the device's wait; not a failure:
    /// the frame loop answers its commands and asks again.
    #[error("no frame yet")]
    NotYet,
}

/// Which backend delivers frames; its name (strum's Display) is the D-Bus
/// `Backend` property and the recordings' `backend`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, strum::Display, strum::IntoStaticStr)]
#[strum(serialize_all = "lowercase")]
pub enum BackendName {
    Sim,
    Replay,
    Opt8241,
}

/// A source of sensor frames.
pub trait Backend: Send {
    /// Which backend this is (a wrapper reports the backend it wraps).
    fn kind(&self) -> BackendName;
    /// Human-readable device (model, file or USB path).
    fn device(&self) -> String;
    /// The source's own serial (the board's USB serial), when it has one.
    fn serial(&self) -> Option<String> {
        None
    }
    fn sensor(&self) -> &SensorParams;
    fn limits(&self) -> Limits {
        Limits::DEFAULT
    }
    fn settings(&self) -> CaptureSettings;
    /// Applies new capture settings from the next frame on.
    fn configure(&mut self, settings: &CaptureSettings) -> Result<(), BackendError>;
    /// The mode changed: backends that model the scene or drive lights adapt.
    fn set_mode(&mut self, _mode: ModeId) {}
    /// The rate at which the frame loop must pace captures, for sources
    /// without a frame clock of their own (the simulator, a replay); `None`
    /// when `capture` itself waits for the device's next frame.
    fn paced_rate_hz(&self) -> Option<f64> {
        None
    }
    /// Writes the next frame into `frame`: at once for a paced source
    /// ([`Backend::paced_rate_hz`]), else blocking until the device has one,
    /// but at most a short slice (the board's `FRAME_SLICE`, 100 ms), then
    /// [`BackendError::NotYet`], so that the frame loop's commands never
    /// wait for a silent device.
    fn capture(
        &mut self,
        illumination: &Illumination,
        frame: &mut Frame,
    ) -> Result<(), BackendError>;
    /// True when frames come from a recording: their sequence numbers, not
    /// the illumination asked for, tell which two-shot frame is A and which B.
    fn replays(&self) -> bool {
        false
    }
    /// A dark frame that came with the source (a recording's), handed over once.
    fn take_dark_frame(&mut self) -> Option<(u32, Image<f32>)> {
        None
    }
    /// Starts (or stops) summing each frame's (I, Q) for the phase
    /// calibration: raw-quad sources only.
    fn measure_phase(&mut self, _on: bool) -> Result<(), BackendError> {
        Err(no_phase_quads(self.kind()))
    }
    /// The (I, Q) sums of the frame just captured, while measuring; `None`
    /// for a frame that has none (a stand-in's).
    fn take_phase_sums(&mut self) -> Option<PhaseSums> {
        None
    }
    /// Decodes with this phase axis from the next frame on (`None`: quad 0
    /// alone): raw-quad sources only.
    fn set_phase_axis(&mut self, _axis: Option<PhaseAxis>) -> Result<(), BackendError> {
        Err(no_phase_quads(self.kind()))
    }
    /// The rig `[lights]` drives, and why it refused the last drive asked;
    /// `None` when sdid drives no lights.
    fn lights(&self) -> Option<LightsState> {
        None
    }
}

/// What drives the light sources, as a job needs to know it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LightsState {
    /// The rig, as `LightSource::describe` says.
    pub rig: String,
    /// Why the last drive asked was refused; `None` when it is in effect.
    pub refused: Option<String>,
}

/// The error of a phase request to a source without raw quads.
pub fn no_phase_quads(kind: BackendName) -> BackendError {
    BackendError::Failed(format!(
        "the {kind} backend has no phase quads: phase calibration needs the OPT8241-CDK \
         (backend = \"opt8241\")"
    ))
}

/// Backends selectable by name ("auto": the board when one is attached, else the simulator).
pub use sdi_config::BackendKind;

#[cfg(test)]
mod tests {
    use super::BackendName;

    /// The strings of the D-Bus `Backend` property and the recordings'
    /// `backend` field: a contract, so pinned here.
    #[test]
    fn backend_names() {
        let names =
            [BackendName::Sim, BackendName::Replay, BackendName::Opt8241].map(|b| b.to_string());
        assert_eq!(names, ["sim", "replay", "opt8241"]);
    }
}
