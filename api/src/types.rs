//! Typed replies and properties. Each is an `a{sv}` dictionary on the wire
//! (zvariant's `SerializeDict`), so clients in any language read them by
//! key, and fields can be added without breaking old clients.

use zbus::zvariant::{DeserializeDict, OwnedValue, SerializeDict, Type, Value};

/// The `Job` property: the job holding the camera (dark frame,
/// calibration, phase calibration) and its progress.
#[derive(
    Debug, Clone, Default, PartialEq, Eq, SerializeDict, DeserializeDict, Type, Value, OwnedValue,
)]
#[zvariant(signature = "a{sv}")]
pub struct JobProgress {
    /// "dark frame", "calibration", "phase calibration"; "" when none runs.
    pub name: String,
    /// Frames the job has taken so far.
    pub frames_done: u32,
    /// Frames it takes in all (without the few its settings need to settle).
    pub frames_total: u32,
}

/// The `Stats` property, emitted about once a second.
#[derive(Debug, Clone, PartialEq, SerializeDict, DeserializeDict, Type, Value, OwnedValue)]
#[zvariant(signature = "a{sv}")]
pub struct Stats {
    /// Frames captured since start.
    pub frames: u64,
    /// Frames per second over the last window; 0 once frames stop (no
    /// frame for three frame periods, at least 2 s, or the source stalled).
    pub fps: f64,
    /// Seconds since the last frame was captured; -1 before the first.
    pub last_frame_age_s: f64,
    /// Mean capture-to-output processing time over the last window, microseconds.
    pub latency_us: f64,
    /// Worst processing time over the last window, microseconds.
    pub latency_max_us: f64,
    /// Frames the view output skipped (reader too slow).
    pub dropped_view: u64,
    /// Frames the recorder could not queue.
    pub dropped_recording: u64,
    /// False while the source delivers no frames: the board unplugged and
    /// nothing standing in, a replay at its end, a failing capture.
    pub device_available: bool,
    /// The backend's own words on its state ("" when it has none).
    pub device_state: String,
    /// Why the daemon last stopped a recording by itself (size limit, free
    /// space, disk full); "" when it has not.
    pub recording_stopped: String,
    /// The board's sensor temperature (tsensor), degrees Celsius, polled
    /// every 5 s while streaming; NaN without a board.
    pub board_temperature_c: f64,
    /// The illumination driver's temperature (tillum), degrees Celsius;
    /// NaN without a board.
    pub illumination_temperature_c: f64,
    /// Times the board reported an output overflow (op_overflow); each
    /// dropped the frame it was seen with.
    pub output_overflows: u64,
}

impl Default for Stats {
    /// Nothing counted yet; no board temperatures.
    fn default() -> Self {
        Self {
            frames: 0,
            fps: 0.0,
            last_frame_age_s: 0.0,
            latency_us: 0.0,
            latency_max_us: 0.0,
            dropped_view: 0,
            dropped_recording: 0,
            device_available: false,
            device_state: String::new(),
            recording_stopped: String::new(),
            board_temperature_c: f64::NAN,
            illumination_temperature_c: f64::NAN,
            output_overflows: 0,
        }
    }
}

/// `CaptureDarkFrame`'s reply: statistics of the averaged dark frames.
#[derive(Debug, Clone, Default, PartialEq, SerializeDict, DeserializeDict, Type)]
#[zvariant(signature = "a{sv}")]
pub struct DarkFrameReply {
    pub frames: u32,
    pub mean_dn: f64,
    /// Mean per-pixel temporal variance, DN^2: the read noise (eq. skellamvar with no light).
    pub read_noise_variance_dn2: f64,
    /// Spatial standard deviation of the dark frame, DN.
    pub fixed_pattern_sigma_dn: f64,
}

/// `Calibrate`'s reply: the dark statistics, then the photon-transfer fit
/// sigma^2 = g |mu| + sigma_read^2 with standard errors, and where the fit
/// was stored (or why it could not be).
#[derive(Debug, Clone, Default, PartialEq, SerializeDict, DeserializeDict, Type)]
#[zvariant(signature = "a{sv}")]
pub struct CalibrationReply {
    pub frames: u32,
    pub mean_dn: f64,
    pub read_noise_variance_dn2: f64,
    pub fixed_pattern_sigma_dn: f64,
    /// Gain g = rho eta, DN per electron.
    pub gain_dn_per_electron: f64,
    pub gain_se: f64,
    pub ptc_read_variance_dn2: f64,
    pub ptc_read_variance_se_dn2: f64,
    pub reduced_chi2: f64,
    pub ptc_points: u32,
    /// Path of the stored calibration.
    pub stored: Option<String>,
    /// Why the calibration could not be stored (it is in use all the same).
    pub store_error: Option<String>,
}

/// `CalibratePhase`'s reply: the axis of LS1 - LS2 in the quads' (I, Q)
/// plane, measured with LS1 alone lit, and where it was stored.
#[derive(Debug, Clone, Default, PartialEq, SerializeDict, DeserializeDict, Type)]
#[zvariant(signature = "a{sv}")]
pub struct PhaseCalibrationReply {
    /// Frames summed.
    pub frames: u32,
    /// The axis, atan2(Q, I) of LS1's light: the delay on the LED path as
    /// a phase of the modulation, degrees in [-180, 180].
    pub angle_deg: f64,
    /// Mean amplitude of LS1's light per pixel and frame, DN.
    pub amplitude_dn: f64,
    /// |sum of (I, Q)| / sum of |(I, Q)| over the pixels: near 1 when every
    /// pixel saw LS1's light at one phase.
    pub coherence: f64,
    /// The rig sdid lit LS1 alone with; "" when it drives no lights (LS2
    /// had to be covered by hand).
    pub lights: String,
    /// Path of the stored calibration.
    pub stored: Option<String>,
    /// Why the calibration could not be stored (it is in use all the same).
    pub store_error: Option<String>,
}

/// `StopRecording`'s reply.
#[derive(Debug, Clone, Default, PartialEq, SerializeDict, DeserializeDict, Type)]
#[zvariant(signature = "a{sv}")]
pub struct RecordingReply {
    /// The Recording label (path) of the recording that ended.
    pub path: String,
    pub frames: u64,
    pub dropped: u64,
}
