//! `sdictl export rec.sdirec out.npy`: a recording's frames as one float32
//! array of shape (frames, height, width), in DN, dark frame not subtracted.

use std::fs::OpenOptions;
use std::io::{BufWriter, Write};
use std::path::Path;

use sdi_daemon::recording::{Record, RecordingReader};

use super::errors::OnlineError;

pub fn run(recording: &Path, out: &Path, json: bool) -> Result<(), OnlineError> {
    let reader = RecordingReader::open(recording)
        .map_err(|e| OnlineError::Invalid(format!("{}: {e}", recording.display())))?;
    let header = reader.header().clone();
    let (w, h) = (header.sensor.width, header.sensor.height);
    let mut reader = reader;
    let mut data: Vec<f32> = Vec::new();
    let mut frames = 0usize;
    let mut skipped = 0usize;
    for rec in reader.by_ref() {
        if let Record::Frame { frame, .. } = rec {
            if frame.width() == w && frame.height() == h {
                data.extend_from_slice(&frame.dn.data);
                frames += 1;
            } else {
                skipped += 1;
            }
        }
    }
    let damaged = reader.damaged_tail().map(str::to_owned);
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(out)
        .map_err(|e| OnlineError::Failed(format!("{}: {e}", out.display())))?;
    let mut wtr = BufWriter::new(file);
    sdi_daemon::modes::write_npy_f32(&mut wtr, &[frames, h, w], &data)
        .and_then(|()| wtr.flush())
        .map_err(|e| OnlineError::Failed(format!("{}: {e}", out.display())))?;
    if json {
        println!(
            "{}",
            serde_json::json!({"frames": frames, "width": w, "height": h, "mode": header.mode,
                "skipped": skipped, "damaged_tail": damaged})
        );
    } else {
        println!("{frames} frames of {w}x{h} -> {}", out.display());
        if let Some(d) = damaged {
            eprintln!("note: the recording ends in a damaged record ({d}); every complete frame was exported");
        }
    }
    Ok(())
}
