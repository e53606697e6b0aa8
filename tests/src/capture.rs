//! ffmpeg as the V4L2 capture client a user would run: the one place the
//! tests read frames from a video node with it (a reader that streams until
//! killed, with its own filters, stays in its test).

use std::path::Path;
use std::process::Command;

use crate::clients::mean_rgb;

/// Longest one read may take: ffmpeg's open and its first frames under TCG
/// beside a busy sdid.
const READ_TIMEOUT_S: &str = "180";

/// Reads `frames` frames from the V4L2 node `dev` into `out` as raw video in
/// ffmpeg's pixel format `pix_fmt` (the node's own, or a conversion such as
/// `rgb24`) and returns the bytes.
pub fn read_frames(dev: &Path, frames: u32, pix_fmt: &str, out: &Path) -> Result<Vec<u8>, String> {
    let o = Command::new("timeout")
        .args([
            READ_TIMEOUT_S,
            "ffmpeg",
            "-hide_banner",
            "-loglevel",
            "error",
        ])
        .args(["-nostdin", "-y", "-f", "v4l2", "-i"])
        .arg(dev)
        .args(["-frames:v", &frames.to_string(), "-c:v", "rawvideo"])
        .args(["-pix_fmt", pix_fmt, "-f", "rawvideo"])
        .arg(out)
        .output()
        .map_err(|e| format!("spawn ffmpeg: {e}"))?;
    if !o.status.success() {
        return Err(format!(
            "ffmpeg on {} failed ({}): {}",
            dev.display(),
            o.status,
            String::from_utf8_lossy(&o.stderr)
        ));
    }
    std::fs::read(out).map_err(|e| format!("read {}: {e}", out.display()))
}

/// The mean colour of the last of 5 frames ffmpeg reads from the view node
/// `dev` (`width` x `height`, converted to RGB): the first frames may
/// predate a mode switch the caller waited for.
pub fn last_frame_mean_rgb(dev: &Path, width: usize, height: usize) -> [f64; 3] {
    let out = std::env::temp_dir().join("sdi-capture-view.rgb");
    let bytes = read_frames(dev, 5, "rgb24", &out).unwrap_or_else(|e| panic!("{e}"));
    let frame = width * height * 3;
    assert_eq!(bytes.len(), 5 * frame, "5 whole frames of {width}x{height}");
    mean_rgb(&bytes[4 * frame..])
}
