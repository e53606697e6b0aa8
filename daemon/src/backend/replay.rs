//! Plays a recording back at its frame rate, optionally looping.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use sdi_core::modulation::Illumination;
use sdi_core::sensor::SensorParams;
use sdi_core::{Frame, Image};

use super::{Backend, BackendError, BackendName, CaptureSettings};
use sdi_recording::{Header, Record, RecordingReader};

pub struct ReplayBackend {
    path: PathBuf,
    looping: bool,
    reader: RecordingReader<BufReader<File>>,
    header: Header,
    settings: CaptureSettings,
    /// Dark frame stored in the recording, if any.
    dark: Option<(u32, Image<f32>)>,
    frames_read: u64,
}

impl ReplayBackend {
    pub fn open(path: &Path, looping: bool) -> Result<Self, BackendError> {
        let reader = RecordingReader::open(path)
            .map_err(|e| BackendError::Unavailable(format!("{}: {e}", path.display())))?;
        let header = reader.header().clone();
        let settings = CaptureSettings {
            exposure_us: header.exposure_us,
            frame_rate_hz: header.frame_rate_hz,
            modulation_hz: header.modulation_hz,
        };
        Ok(Self {
            path: path.to_owned(),
            looping,
            reader,
            header,
            settings,
            dark: None,
            frames_read: 0,
        })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    fn next_frame(&mut self) -> Result<Frame, BackendError> {
        for _attempt in 0..2 {
            while let Some(rec) = self.reader.next_record() {
                match rec {
                    Record::Frame { frame, .. } => {
                        self.frames_read += 1;
                        return Ok(frame);
                    }
                    Record::Dark { frames, dn } => self.dark = Some((frames, dn)),
                    Record::End { .. } => {}
                }
            }
            if let Some(why) = self.reader.damaged_tail() {
                tracing::warn!(path = %self.path.display(), "recording ends in a damaged record: {why}");
            }
            if !self.looping || self.frames_read == 0 {
                return Err(BackendError::EndOfStream);
            }
            self.reader = RecordingReader::open(&self.path)
                .map_err(|e| BackendError::Unavailable(e.to_string()))?;
            self.frames_read = 0;
        }
        Err(BackendError::EndOfStream)
    }
}

impl Backend for ReplayBackend {
    fn kind(&self) -> BackendName {
        BackendName::Replay
    }

    fn device(&self) -> String {
        self.path.display().to_string()
    }

    fn sensor(&self) -> &SensorParams {
        &self.header.sensor
    }

    fn settings(&self) -> CaptureSettings {
        self.settings
    }

    /// Only the playback rate can change; exposure and modulation are fixed in the file.
    fn configure(&mut self, s: &CaptureSettings) -> Result<(), BackendError> {
        if s.exposure_us != self.settings.exposure_us
            || s.modulation_hz != self.settings.modulation_hz
        {
            return Err(BackendError::OutOfRange(
                "a recording's exposure and modulation are fixed; only FrameRate can change".into(),
            ));
        }
        self.settings.frame_rate_hz = s.frame_rate_hz;
        Ok(())
    }

    fn paced_rate_hz(&self) -> Option<f64> {
        Some(self.settings.frame_rate_hz)
    }

    fn capture(
        &mut self,
        _illumination: &Illumination,
        frame: &mut Frame,
    ) -> Result<(), BackendError> {
        *frame = self.next_frame()?;
        Ok(())
    }

    fn replays(&self) -> bool {
        true
    }

    fn take_dark_frame(&mut self) -> Option<(u32, Image<f32>)> {
        self.dark.take()
    }
}
