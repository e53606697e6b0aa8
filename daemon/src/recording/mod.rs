//! Crash-safe recordings of raw sensor frames with their metadata.

pub mod format;
pub mod reader;
pub mod writer;

pub use format::{Calibration, Header, Record};
pub use reader::{ReadError, RecordingReader};
pub use writer::{RecordingWriter, Summary};
