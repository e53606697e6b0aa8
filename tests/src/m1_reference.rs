//! The independent M1 that the separation tests hold `sdictl separate`
//! against: a recording's dark-subtracted frames read with the format's own
//! reader, and M1 computed over them in numpy.
//!
//! sdi-cli's tests include this file by path (they cannot depend on
//! sdi-tests, which depends on sdi-cli), so it uses only std, sdi-core and
//! sdi-recording.

use std::path::Path;
use std::process::Command;

use sdi_core::Image;
use sdi_recording::{Record, RecordingReader};

/// Frames of a recording, the latest dark frame subtracted, as an .npy
/// (N, H, W); the frame count.
pub fn recording_to_npy(rec: &Path, npy: &Path) -> usize {
    let reader = RecordingReader::open(rec).unwrap();
    let mut dark: Option<Image<f32>> = None;
    let mut data = Vec::new();
    let (mut n, mut w, mut h) = (0, 0, 0);
    for r in reader {
        match r {
            Record::Dark { dn, .. } => dark = Some(dn),
            Record::Frame { frame, .. } => {
                let d = dark.as_ref().expect("a dark frame before the frames");
                data.extend(frame.dn.data.iter().zip(&d.data).map(|(a, b)| a - b));
                (w, h) = (frame.width(), frame.height());
                n += 1;
            }
            _ => {}
        }
    }
    sdi_core::npy::write_f32(std::fs::File::create(npy).unwrap(), &[n, h, w], &data).unwrap();
    n
}

/// A python3 with numpy, or None after one `SKIPPED` line (a failure when
/// `SDI_REQUIRE_VM` is set: CI installs numpy).
pub fn numpy_python() -> Option<String> {
    let found = ["python3", "/usr/bin/python3"].into_iter().find(|py| {
        Command::new(py)
            .args(["-c", "import numpy"])
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if found.is_none() {
        super::skip::unavailable(
            "SDI_REQUIRE_VM",
            format_args!("numpy comparison: no python3 with numpy (apt-get install python3-numpy)"),
        );
    }
    found.map(str::to_owned)
}

/// M1 in numpy: mean and unbiased variance over axis 0, then
/// (I+, I-) = ((max(v - r, 0) / g^2 +- m / g) / 2; the largest difference
/// from the separated stack `sep` relative to max(|numpy|, 1).
pub fn numpy_m1_max_rel_diff(py: &str, frames: &Path, sep: &Path, g: f64, r: f64) -> f64 {
    let code = format!(
        "import numpy as np\n\
         x = np.load('{}').astype(np.float64)\n\
         s = np.load('{}').astype(np.float64)\n\
         m = x.mean(0); v = x.var(0, ddof=1)\n\
         S = np.maximum(v - {r:.17e}, 0) / {g:.17e}**2; D = m / {g:.17e}\n\
         ref = np.stack([0.5 * (S + D), 0.5 * (S - D)])\n\
         print((np.abs(ref - s) / np.maximum(np.abs(ref), 1.0)).max())\n",
        frames.display(),
        sep.display()
    );
    let o = Command::new(py).args(["-c", &code]).output().unwrap();
    assert!(
        o.status.success(),
        "numpy M1: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).trim().parse().unwrap()
}
