//! `loopback_tool write DEV FORMAT W H FPS SECONDS [write|mmap]`: publishes a
//! moving test pattern through the glue (for manual checks in the VM).
//! `loopback_tool bench DEV_OURS DEV_FFMPEG FRAMES`: see `sdi_tests::bench`.
//! `loopback_tool latency DEV SECONDS`: reads DEV as a V4L2 client (mmap,
//! 4 buffers) and prints how old each new frame is when it is dequeued:
//! CLOCK_MONOTONIC at DQBUF minus the buffer's timestamp (the writer's
//! capture time), median and 99th percentile.

use std::time::{Duration, Instant};

use std::path::Path;

use v4l2loopback_glue::{IoMethod, LoopbackFormat, LoopbackWriter, PixelFormat};

fn parse_format(s: &str) -> PixelFormat {
    match s {
        "grey" => PixelFormat::Grey,
        "y16" => PixelFormat::Y16,
        "yuyv" => PixelFormat::Yuyv,
        "rgb24" => PixelFormat::Rgb24,
        _ => panic!("format must be grey|y16|yuyv|rgb24"),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    match args.get(1).map(String::as_str) {
        Some("write") if args.len() >= 8 => {
            let num = |i: usize| args[i].parse::<u32>().expect("number");
            let io = if args.get(8).map(String::as_str) == Some("write") {
                IoMethod::Write
            } else {
                IoMethod::Mmap
            };
            let cfg = LoopbackFormat {
                width: num(4),
                height: num(5),
                format: parse_format(&args[3]),
                fps: num(6),
                io,
            };
            let mut w = match LoopbackWriter::open(&args[2], cfg) {
                Ok(w) => w,
                Err(e) => {
                    eprintln!("loopback_tool: {e}");
                    std::process::exit(1);
                }
            };
            if std::env::var_os("SDI_SUSTAIN").is_some() {
                w.set_sustain_framerate(true);
            }
            eprintln!(
                "writing {cfg} via {:?}, module {:?}, features {:?}",
                w.io_method(),
                w.module_version(),
                w.features()
            );
            let (gw, gh) = (cfg.width as usize, cfg.height as usize);
            let mut grey = vec![0u8; gw * gh];
            let packer = sdi_core::view::Packer::new(gw, gh, cfg.format);
            let mut frame = vec![0u8; cfg.frame_bytes()];
            let start = Instant::now();
            let period = Duration::from_micros(1_000_000 / u64::from(cfg.fps));
            let mut k = 0u64;
            while start.elapsed().as_secs() < u64::from(num(7)) {
                for (i, g) in grey.iter_mut().enumerate() {
                    *g = (i as u64 + k) as u8;
                }
                let src = sdi_core::view::Src::packed(&grey, gw, gh, 1);
                if let Err(e) = packer.grey8(src, &mut frame) {
                    eprintln!("loopback_tool: {e}");
                    std::process::exit(1);
                }
                if let Err(e) = w.write(&frame, start.elapsed().as_micros() as u64) {
                    eprintln!("loopback_tool: {e}");
                    std::process::exit(1);
                }
                k += 1;
                std::thread::sleep(period);
            }
            eprintln!("wrote {k} frames");
        }
        Some("convert") => {
            let ms = sdi_tests::bench::converter(200);
            println!("RGB8->YUYV 640x480: {ms:.3} ms per frame");
        }
        Some("bench") if args.len() >= 5 => {
            sdi_tests::bench::run(&args[2], &args[3], args[4].parse().expect("frames"))
        }
        Some("latency") if args.len() >= 4 => {
            let seconds: f64 = args[3].parse().expect("seconds");
            latency(&args[2], Duration::from_secs_f64(seconds));
        }
        _ => {
            eprintln!(
                "usage: loopback_tool write DEV grey|y16|yuyv|rgb24 W H FPS SECONDS [write|mmap]"
            );
            eprintln!("       loopback_tool bench DEV_OURS DEV_FFMPEG FRAMES");
            eprintln!("       loopback_tool latency DEV SECONDS");
            std::process::exit(2);
        }
    }
}

/// CLOCK_MONOTONIC in microseconds: the clock V4L2 buffer timestamps use.
fn monotonic_us() -> i64 {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).expect("clock");
    t.tv_sec() * 1_000_000 + t.tv_nsec() / 1_000
}

/// Prints "latency DEV: N frames, median X us, p99 Y us, max Z us, B stamps
/// went back" for the frames read in `window`. A buffer whose timestamp was
/// seen before (the module re-sending the last frame) is not a new frame and
/// is skipped; one stamped earlier than the last is counted in B.
fn latency(dev: &str, window: Duration) {
    let mut stream =
        v4l2loopback_glue::CaptureReader::open(Path::new(dev), 4).expect("mmap streaming");
    let start = Instant::now();
    let mut last_stamp_us = i64::MIN;
    let mut ages_us = Vec::new();
    // Buffers stamped earlier than the one before (never expected).
    let mut went_back = 0u64;
    while start.elapsed() < window {
        let stamp_us = stream
            .next(Duration::from_secs(10))
            .expect("dequeue")
            .timestamp_us;
        let now_us = monotonic_us();
        if stamp_us > last_stamp_us {
            ages_us.push(now_us - stamp_us);
            last_stamp_us = stamp_us;
        } else if stamp_us < last_stamp_us {
            went_back += 1;
        }
    }
    ages_us.sort_unstable();
    let at = |q: usize| {
        ages_us
            .get((ages_us.len().max(1) - 1) * q / 100)
            .copied()
            .unwrap_or(0)
    };
    println!(
        "latency {dev}: {} frames, median {} us, p99 {} us, max {} us, {went_back} stamps went back",
        ages_us.len(),
        at(50),
        at(99),
        at(100)
    );
}
