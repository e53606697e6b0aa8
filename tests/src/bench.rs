//! Write-path benchmark (run inside the VM): frames/s and CPU time of the
//! glue (mmap streaming and write()) against `ffmpeg -f v4l2` writing the
//! same raw frames, side by side, at 640x480 YUYV and Y16.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use nix::sys::resource::{getrusage, UsageWho};
use sdi_core::view::{Packer, Src};
use v4l2loopback_glue::{IoMethod, LoopbackFormat, LoopbackWriter, PixelFormat};

fn cpu_s(who: UsageWho) -> f64 {
    getrusage(who).map_or(0.0, |u| {
        let t = |tv: nix::sys::time::TimeVal| tv.tv_sec() as f64 + tv.tv_usec() as f64 * 1e-6;
        t(u.user_time()) + t(u.system_time())
    })
}

/// (fps, CPU ms per frame)
fn ours(dev: &str, cfg: LoopbackFormat, frames: u32, packed: bool) -> (f64, f64) {
    let mut w = LoopbackWriter::open(dev, cfg).expect("open writer");
    assert_eq!(w.io_method(), cfg.io);
    let (wd, ht) = (cfg.width as usize, cfg.height as usize);
    let rgb: Vec<u8> = (0..wd * ht * 3).map(|i| (i % 251) as u8).collect();
    let dn: Vec<f32> = (0..wd * ht).map(|i| (i % 4000) as f32 - 2000.0).collect();
    let raw = vec![0x55u8; cfg.frame_bytes()];
    let packer = Packer::new(wd, ht, cfg.format);
    let mut frame = vec![0u8; cfg.frame_bytes()];
    let (c0, t0) = (cpu_s(UsageWho::RUSAGE_THREAD), Instant::now());
    for k in 0..frames {
        let ts = u64::from(k) * 33_333;
        let bytes = match cfg.format {
            _ if packed => &raw,
            PixelFormat::Y16 => {
                packer
                    .signed_dn(Src::packed(&dn, wd, ht, 1), &mut frame)
                    .expect("pack Y16");
                &frame
            }
            _ => {
                packer
                    .rgb8(Src::packed(&rgb, wd, ht, 3), &mut frame)
                    .expect("pack RGB");
                &frame
            }
        };
        w.write(bytes, ts).expect("write frame");
    }
    let (dt, dc) = (
        t0.elapsed().as_secs_f64(),
        cpu_s(UsageWho::RUSAGE_THREAD) - c0,
    );
    (f64::from(frames) / dt, dc * 1e3 / f64::from(frames))
}

/// ffmpeg writing `frames` copies of one raw frame; returns (wall s, CPU s).
fn ffmpeg_run(dev: &str, cfg: LoopbackFormat, raw: &Path, frames: u32) -> (f64, f64) {
    let c0 = cpu_s(UsageWho::RUSAGE_CHILDREN);
    let t0 = Instant::now();
    let st = Command::new("ffmpeg")
        .args([
            "-hide_banner",
            "-loglevel",
            "error",
            "-nostdin",
            "-stream_loop",
            "-1",
            "-f",
            "rawvideo",
        ])
        .args([
            "-pix_fmt",
            cfg.format.ffmpeg_name(),
            "-s",
            &format!("{}x{}", cfg.width, cfg.height),
        ])
        .arg("-i")
        .arg(raw)
        .args([
            "-frames:v",
            &frames.to_string(),
            "-c:v",
            "rawvideo",
            "-f",
            "v4l2",
            dev,
        ])
        .status()
        .expect("spawn ffmpeg");
    assert!(st.success(), "ffmpeg writer failed");
    (
        t0.elapsed().as_secs_f64(),
        cpu_s(UsageWho::RUSAGE_CHILDREN) - c0,
    )
}

/// ffmpeg over 4N frames: (fps including its start-up, marginal fps from
/// the N vs 4N difference or NaN when noise hides it, CPU ms per frame).
fn ffmpeg(dev: &str, cfg: LoopbackFormat, raw: &Path, frames: u32) -> (f64, f64, f64) {
    let (t1, _) = ffmpeg_run(dev, cfg, raw, frames);
    let (t4, c4) = ffmpeg_run(dev, cfg, raw, 4 * frames);
    let marginal = if t4 > t1 + 0.05 {
        f64::from(3 * frames) / (t4 - t1)
    } else {
        f64::NAN
    };
    (
        f64::from(4 * frames) / t4,
        marginal,
        c4 * 1e3 / f64::from(4 * frames),
    )
}

/// RGB->YUYV packing alone (ms per frame).
pub fn converter(frames: u32) -> f64 {
    let (w, h) = (640usize, 480usize);
    let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i % 251) as u8).collect();
    let mut out = vec![0u8; w * h * 2];
    let packer = Packer::new(w, h, PixelFormat::Yuyv);
    let t0 = Instant::now();
    for _ in 0..frames {
        packer
            .rgb8(Src::packed(&rgb, w, h, 3), &mut out)
            .expect("convert");
    }
    t0.elapsed().as_secs_f64() * 1e3 / f64::from(frames)
}

/// Runs all cases; `dev_ours` and `dev_ffmpeg` are separate nodes per
/// format pair: ours uses `{dev}` for YUYV and the next number for Y16.
pub fn run(dev_ours: &str, dev_ffmpeg: &str, frames: u32) {
    let ms = converter(frames);
    println!("convert RGB8->YUYV 640x480: {ms:.3} ms/frame");
    let next = |d: &str| {
        let n: u32 = d
            .trim_start_matches("/dev/video")
            .parse()
            .expect("/dev/videoN");
        format!("/dev/video{}", n + 1)
    };
    let tmp = std::env::temp_dir();
    for (fmt, ours_dev, ff_dev) in [
        (
            PixelFormat::Yuyv,
            dev_ours.to_owned(),
            dev_ffmpeg.to_owned(),
        ),
        (PixelFormat::Y16, next(dev_ours), next(dev_ffmpeg)),
    ] {
        let cfg = LoopbackFormat {
            width: 640,
            height: 480,
            format: fmt,
            fps: 30,
            io: IoMethod::Mmap,
        };
        let raw = tmp.join(format!("bench-{}.raw", fmt.ffmpeg_name()));
        std::fs::write(&raw, vec![0x55u8; cfg.frame_bytes()]).expect("write raw frame");
        let mm = ours(&ours_dev, cfg, frames, false);
        let wr = ours(
            &ours_dev,
            LoopbackFormat {
                io: IoMethod::Write,
                ..cfg
            },
            frames,
            false,
        );
        let mr = ours(&ours_dev, cfg, frames, true);
        let ff = ffmpeg(&ff_dev, cfg, &raw, frames);
        let input = if fmt == PixelFormat::Y16 {
            "signed f32 DN"
        } else {
            "RGB8"
        };
        println!("{fmt} 640x480 from {input} ({frames} frames):");
        println!(
            "  glue mmap   : {:8.1} fps, {:6.3} ms CPU/frame",
            mm.0, mm.1
        );
        println!(
            "  glue write(): {:8.1} fps, {:6.3} ms CPU/frame",
            wr.0, wr.1
        );
        println!(
            "  glue mmap, pre-packed raw input: {:8.1} fps, {:6.3} ms CPU/frame",
            mr.0, mr.1
        );
        println!(
            "  ffmpeg v4l2 : {:8.1} fps incl. start-up ({:.1} marginal), {:6.3} ms CPU/frame (raw input, no conversion)",
            ff.0, ff.1, ff.2
        );
        println!(
            "  ratio glue-mmap/ffmpeg: fps x{:.2} (x{:.2} vs marginal), CPU/frame x{:.2}; mmap/write(): fps x{:.2}",
            mm.0 / ff.0,
            mm.0 / ff.1,
            mm.1 / ff.2,
            mm.0 / wr.0
        );
        println!(
            "  ratio raw glue-mmap/ffmpeg marginal: fps x{:.2}, CPU/frame x{:.2}",
            mr.0 / ff.1,
            mr.1 / ff.2
        );
    }
}
