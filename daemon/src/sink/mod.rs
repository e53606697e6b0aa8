//! Where processed frames go: a v4l2loopback device, PipeWire nodes, or the
//! y4m fallback. Each sink takes its pictures from the [`OutFrame`] (each
//! rendered once, through [`sdi_core::view::ViewRenderer`], whichever sink
//! asks first) and only publishes the bytes.
//! Each sink runs on its own thread ([`output`]) so a slow reader never
//! stalls the frame loop or another sink.

pub mod loopback;
pub mod output;
pub mod pipewire;
pub mod pipewire_launch;
pub mod select;
pub mod system_feed;
pub mod y4m;

use crate::out_frame::OutFrame;

/// Which sink publishes; its name (strum's Display) is the one sdid shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, strum::Display, strum::IntoStaticStr)]
#[strum(serialize_all = "lowercase")]
pub enum SinkKindName {
    Loopback,
    Pipewire,
    Y4m,
}

/// What a sink publishes, for the D-Bus properties.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SinkInfo {
    pub kind: SinkKindName,
    pub device: String,
    /// Pixel format as a FourCC-like name ("YUYV", "C444" ...).
    pub format: String,
    pub width: u32,
    pub height: u32,
}

/// Why a sink could not write.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    #[error("output device unavailable: {0}")]
    Loopback(#[from] v4l2loopback_glue::GlueError),
    #[error(transparent)]
    CameraNotInstalled(#[from] pipewire_launch::NotInstalled),
    #[error("output device unavailable: {0}")]
    Camera(#[from] pipewire_launch::ConnectError),
    /// The PipeWire camera waits for this user's PipeWire to come up.
    #[error("output device unavailable: no PipeWire running for this user yet")]
    NoPipewire,
    /// The PipeWire camera cannot carry this camera (why).
    #[error("output device unavailable: {0}")]
    PipewireRefused(&'static str),
    /// Between attempts to start the camera process again.
    #[error("output device unavailable: the PipeWire camera process is gone")]
    CameraGone,
    #[error("output device unavailable: rendering the view: {0}")]
    Render(#[from] sdi_core::view::PackError),
    #[error("output device unavailable: y4m output: {0}")]
    Y4m(#[source] std::io::Error),
    #[error("output I/O error: {0}")]
    Io(#[from] std::io::Error),
}

/// The sinks sdid feeds: the primary one (the D-Bus sink properties) and
/// those fed beside it from the same frames (the PipeWire camera beside the
/// loopback nodes, docs/pipewire.md).
pub struct SinkSet {
    pub primary: Box<dyn Sink>,
    pub also: Vec<Box<dyn Sink>>,
}

/// A consumer of processed frames.
pub trait Sink: Send {
    fn info(&self) -> SinkInfo;
    /// Publishes one processed frame, stamped `frame.output.timestamp_us`
    /// where the sink has timestamps; a sink that shows the mode (a node's
    /// description) follows `frame.mode`.
    fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError>;
    /// Publishes a "no signal" frame (sensor paused or unplugged), stamped
    /// `timestamp_us` (CLOCK_MONOTONIC, chosen by the frame loop on the
    /// frames' clock: `crate::publish_clock`) where the sink has timestamps.
    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError>;
    /// How many readers watch the output, where the sink can tell
    /// (v4l2loopback 0.13+); `None`: unknown, assume someone watches.
    fn watchers(&mut self) -> Option<u32> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::SinkKindName;

    /// The names sdid has always shown for its sinks.
    #[test]
    fn sink_kind_names() {
        let names = [
            SinkKindName::Loopback,
            SinkKindName::Pipewire,
            SinkKindName::Y4m,
        ]
        .map(|k| k.to_string());
        assert_eq!(names, ["loopback", "pipewire", "y4m"]);
    }
}
