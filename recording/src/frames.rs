//! A recording's frames as the offline tools use them (`sdictl separate`,
//! Python's `sdi.read_recording`): the latest dark frame record subtracted
//! from each frame after it, frames of another size refused.

use std::io::Read;

use sdi_core::Frame;
use sdi_core::Image;

use crate::{Header, Record, RecordingReader};

/// A frame of another size than the recording's.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("frame {sequence} is {width}x{height}, expected {expected_width}x{expected_height}")]
pub struct SizeChanged {
    pub sequence: u64,
    pub width: usize,
    pub height: usize,
    pub expected_width: usize,
    pub expected_height: usize,
}

/// One frame, dark frame subtracted.
#[derive(Debug, Clone, PartialEq)]
pub struct DarkSubtracted {
    pub frame: Frame,
    /// The mode the frame was recorded in.
    pub mode: String,
    /// The previous frame's mode when this frame's differs.
    pub mode_changed_from: Option<String>,
}

/// The frames of a recording, dark frame subtracted.
pub struct RecordedFrames<R> {
    reader: RecordingReader<R>,
    dark_dn: Option<Image<f32>>,
    last_mode: Option<String>,
}

impl<R: Read> RecordedFrames<R> {
    pub fn new(reader: RecordingReader<R>) -> Self {
        Self {
            reader,
            dark_dn: None,
            last_mode: None,
        }
    }

    pub fn header(&self) -> &Header {
        self.reader.header()
    }

    /// `Some(reason)` when the file ended in a torn or corrupt record.
    pub fn damaged_tail(&self) -> Option<&str> {
        self.reader.damaged_tail()
    }

    /// True while no dark frame record has been read.
    pub fn lacks_dark(&self) -> bool {
        self.dark_dn.is_none()
    }

    /// The mode of the last frame read.
    pub fn last_mode(&self) -> Option<&str> {
        self.last_mode.as_deref()
    }

    /// The next frame; None at the end (or at a damaged record).
    pub fn next_frame(&mut self) -> Result<Option<DarkSubtracted>, SizeChanged> {
        let (w, h) = (self.header().sensor.width, self.header().sensor.height);
        loop {
            match self.reader.next_record() {
                None => return Ok(None),
                Some(Record::Dark { dn, .. }) => self.dark_dn = Some(dn),
                Some(Record::End { .. }) => {}
                Some(Record::Frame { mode, mut frame }) => {
                    if frame.width() != w || frame.height() != h {
                        return Err(SizeChanged {
                            sequence: frame.sequence,
                            width: frame.width(),
                            height: frame.height(),
                            expected_width: w,
                            expected_height: h,
                        });
                    }
                    let mode_changed_from = match self.last_mode.replace(mode.clone()) {
                        Some(m) if m != mode => Some(m),
                        _ => None,
                    };
                    if let Some(d) = self.dark_dn.as_ref().filter(|d| d.same_size(&frame.dn)) {
                        for (v, &k) in frame.dn.data.iter_mut().zip(&d.data) {
                            *v -= k;
                        }
                    }
                    return Ok(Some(DarkSubtracted {
                        frame,
                        mode,
                        mode_changed_from,
                    }));
                }
            }
        }
    }
}
