//! The `.sdirec` recording format of raw sensor frames (`docs/recording.md`):
//! one definition shared by sdid's recorder and replay backend and by
//! sdictl's offline commands. Format, reader and a file writer that is pure
//! I/O; no threads, no D-Bus.
#![forbid(unsafe_code)]

pub mod file_writer;
pub mod format;
pub mod frames;
pub mod reader;

pub use file_writer::RecordingFile;
pub use format::{Calibration, Header, HeaderError, Record};
pub use frames::{DarkSubtracted, RecordedFrames, SizeChanged};
pub use reader::{ReadError, RecordingReader};
