//! `sdictl export rec.sdirec out.npy`: a recording's frames as one float32
//! array of shape (frames, height, width), in DN, dark frame not subtracted.
//! Streams: one frame in memory at a time, whatever the length.

use std::fs::OpenOptions;
use std::io::BufWriter;
use std::path::Path;

use sdi_recording::{Record, RecordingReader};

use crate::exit::CliError;
use crate::offline::frames::NpyOut;
use crate::stdout::outln;

pub fn run(recording: &Path, out: &Path, json: bool) -> Result<(), CliError> {
    let mut reader = RecordingReader::open(recording)
        .map_err(|e| CliError::Usage(format!("{}: {e}", recording.display())))?;
    let header = reader.header().clone();
    let (w, h) = (header.sensor.width, header.sensor.height);
    let failed = |e: std::io::Error| CliError::Runtime(format!("{}: {e}", out.display()));
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(out)
        .map_err(failed)?;
    let write = |reader: &mut RecordingReader<_>| -> std::io::Result<usize> {
        let mut npy = NpyOut::new(BufWriter::new(file), &[h, w])?;
        for rec in reader.by_ref() {
            if let Record::Frame { frame, .. } = rec {
                npy.push(&frame.dn.data)?;
            }
        }
        let frames = npy.count();
        npy.finish(false)?;
        Ok(frames)
    };
    let frames = write(&mut reader).map_err(|e| {
        let _ = std::fs::remove_file(out);
        failed(e)
    })?;
    // The reader refuses frames of another size than the header's.
    let skipped = 0usize;
    let damaged = reader.damaged_tail().map(str::to_owned);
    if json {
        outln!(
            "{}",
            serde_json::json!({"frames": frames, "width": w, "height": h, "mode": header.mode,
                "skipped": skipped, "damaged_tail": damaged})
        )?;
    } else {
        outln!("{frames} frames of {w}x{h} -> {}", out.display())?;
        if let Some(d) = damaged {
            eprintln!("note: the recording ends in a damaged record ({d}); every complete frame was exported");
        }
    }
    Ok(())
}
