//! `loopback_tool write DEV FORMAT W H FPS SECONDS [write|mmap]`: publishes a
//! moving test pattern through the glue (for manual checks in the VM).
//! `loopback_tool bench DEV_OURS DEV_FFMPEG FRAMES`: see `sdi_tests::bench`.

use std::time::{Duration, Instant};

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
            if std::env::var_os("SDI_NO_SUSTAIN").is_some() {
                w.set_sustain_framerate(false);
            }
            eprintln!(
                "writing {cfg} via {:?}, module {:?}, features {:?}",
                w.io_method(),
                w.module_version(),
                w.features()
            );
            let n = (cfg.width * cfg.height) as usize;
            let mut grey = vec![0u8; n];
            let start = Instant::now();
            let period = Duration::from_micros(1_000_000 / u64::from(cfg.fps));
            let mut k = 0u64;
            while start.elapsed().as_secs() < u64::from(num(7)) {
                for (i, g) in grey.iter_mut().enumerate() {
                    *g = (i as u64 + k) as u8;
                }
                if let Err(e) = w.write_grey8(&grey, start.elapsed().as_micros() as u64) {
                    eprintln!("loopback_tool: {e}");
                    std::process::exit(1);
                }
                k += 1;
                std::thread::sleep(period);
            }
            eprintln!("wrote {k} frames");
        }
        Some("convert") => {
            let (scalar, simd) = sdi_tests::bench::converters(200);
            println!("RGB8->YUYV 640x480: scalar {scalar:.3} ms, yuvutils {simd:.3} ms per frame");
        }
        Some("bench") if args.len() >= 5 => {
            sdi_tests::bench::run(&args[2], &args[3], args[4].parse().expect("frames"))
        }
        _ => {
            eprintln!(
                "usage: loopback_tool write DEV grey|y16|yuyv|rgb24 W H FPS SECONDS [write|mmap]"
            );
            eprintln!("       loopback_tool bench DEV_OURS DEV_FFMPEG FRAMES");
            std::process::exit(2);
        }
    }
}
