//! Recordings of raw sensor frames: the format is `sdi-recording`'s; here
//! the daemon's recorder thread that writes them.

pub mod writer;

pub use sdi_recording::{format, Calibration, Header, ReadError, Record, RecordingReader};
pub use writer::{FinishError, RecordingWriter, StopCause, Summary};
