//! Helpers for the v4l2loopback VM tests and bench: module loading, a
//! background writer, ffmpeg / v4l2-compliance runners.

use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use v4l2loopback_glue::{GlueError, Input, LoopbackWriter, OutputConfig, Src};

/// Loads v4l2loopback with one node per (video_nr, label), exclusive_caps=1.
pub fn modprobe(nodes: &[(u32, &str)]) {
    let nrs: Vec<String> = nodes.iter().map(|(n, _)| n.to_string()).collect();
    let labels: Vec<&str> = nodes.iter().map(|(_, l)| *l).collect();
    let caps: Vec<&str> = nodes.iter().map(|_| "1").collect();
    let status = Command::new("modprobe")
        .arg("v4l2loopback")
        .arg(format!("devices={}", nodes.len()))
        .arg(format!("video_nr={}", nrs.join(",")))
        .arg(format!("card_label={}", labels.join(",")))
        .arg(format!("exclusive_caps={}", caps.join(",")))
        .status()
        .expect("spawn modprobe");
    assert!(status.success(), "modprobe v4l2loopback failed");
}

/// What the background writer publishes each frame.
#[derive(Clone)]
pub enum Pattern {
    Rgb8(Vec<u8>),
    Grey8(Vec<u8>),
    SignedDn(Vec<f32>),
}

/// A writer thread publishing `pattern` at ~`fps` until stopped.
pub struct BackgroundWriter {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Result<u64, GlueError>>>,
}

impl BackgroundWriter {
    /// Opens the writer on this thread (so open errors surface here), then
    /// moves it to a thread.
    pub fn start(mut writer: LoopbackWriter, pattern: Pattern) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let cfg = writer.config();
        let (w, h) = (cfg.width as usize, cfg.height as usize);
        let handle = std::thread::spawn(move || {
            let period = Duration::from_micros(1_000_000 / u64::from(cfg.fps));
            let mut ts_us = 1_000_000u64;
            while !flag.load(Ordering::Relaxed) {
                let input = match &pattern {
                    Pattern::Rgb8(d) => Input::Rgb8(Src::packed(d, w, h, 3)),
                    Pattern::Grey8(d) => Input::Grey8(Src::packed(d, w, h, 1)),
                    Pattern::SignedDn(d) => Input::SignedDn(Src::packed(d, w, h, 1)),
                };
                writer.write(input, ts_us)?;
                ts_us += period.as_micros() as u64;
                std::thread::sleep(period);
            }
            Ok(writer.frames_written())
        });
        Self {
            stop,
            handle: Some(handle),
        }
    }

    /// Stops the thread; returns frames written or the writer's error.
    pub fn stop(mut self) -> Result<u64, GlueError> {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .take()
            .expect("joined once")
            .join()
            .expect("writer thread panicked")
    }
}

impl Drop for BackgroundWriter {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Reads `frames` frames from `dev` with ffmpeg, raw bytes in the node's own
/// pixel format (no conversion).
pub fn ffmpeg_read(
    dev: &Path,
    cfg: &OutputConfig,
    frames: u32,
    out: &Path,
) -> Result<Vec<u8>, String> {
    let o = Command::new("timeout")
        .args([
            "180",
            "ffmpeg",
            "-hide_banner",
            "-loglevel",
            "error",
            "-nostdin",
            "-y",
            "-f",
            "v4l2",
        ])
        .arg("-i")
        .arg(dev)
        .args([
            "-frames:v",
            &frames.to_string(),
            "-c:v",
            "rawvideo",
            "-pix_fmt",
            cfg.format.ffmpeg_name(),
        ])
        .args(["-f", "rawvideo"])
        .arg(out)
        .output()
        .map_err(|e| format!("spawn ffmpeg: {e}"))?;
    if !o.status.success() {
        return Err(format!(
            "ffmpeg reader failed ({}): {}",
            o.status,
            String::from_utf8_lossy(&o.stderr)
        ));
    }
    std::fs::read(out).map_err(|e| format!("read {}: {e}", out.display()))
}

/// v4l2-compliance totals.
#[derive(Debug, Clone)]
pub struct Compliance {
    pub total: u32,
    pub succeeded: u32,
    pub failed: u32,
    pub warnings: u32,
    pub failing_tests: Vec<String>,
    pub output: String,
}

/// Runs `v4l2-compliance -d dev` and parses its summary.
pub fn compliance(dev: &Path) -> Result<Compliance, String> {
    let o = Command::new("timeout")
        .args(["120", "v4l2-compliance", "-d"])
        .arg(dev)
        .output()
        .map_err(|e| format!("spawn v4l2-compliance: {e}"))?;
    let output =
        String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    let line = output
        .lines()
        .find(|l| l.starts_with("Total for"))
        .ok_or_else(|| format!("no summary in v4l2-compliance output:\n{output}"))?;
    let num = |key: &str| -> u32 {
        line.split(key)
            .nth(1)
            .and_then(|s| s.trim().split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|s| s.parse().ok())
            .unwrap_or(u32::MAX)
    };
    let total = line
        .split(": ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(u32::MAX);
    let failing_tests = output
        .lines()
        .filter(|l| l.trim_end().ends_with(": FAIL"))
        .map(|l| l.trim().to_owned())
        .collect();
    Ok(Compliance {
        total,
        succeeded: num("Succeeded:"),
        failed: num("Failed:"),
        warnings: num("Warnings:"),
        failing_tests,
        output,
    })
}

/// `v4l2-ctl -D` device caps section mentions Video Capture.
pub fn advertises_capture(dev: &Path) -> bool {
    let o = Command::new("v4l2-ctl")
        .arg("-d")
        .arg(dev)
        .arg("-D")
        .output();
    let Ok(o) = o else { return false };
    let text = String::from_utf8_lossy(&o.stdout);
    // only the "Device Caps" block (the "Capabilities" block lists both)
    text.split("Device Caps")
        .nth(1)
        .is_some_and(|s| s.contains("Video Capture"))
}
