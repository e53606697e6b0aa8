//! End-to-end: the glue publishes frames on v4l2loopback inside the VM and
//! real clients (ffmpeg, v4l2-compliance, OpenCV) read them. One VM boot
//! runs all checks (a boot costs ~3 s).

use std::path::{Path, PathBuf};
use std::process::Command;

use sdi_tests::loopback::{self, BackgroundWriter, Pattern};
use sdi_tests::vm;
use v4l2loopback_glue::{
    find_device, Converter, GlueError, IoMethod, LoopbackWriter, OutputConfig, PixelFormat, Src,
    YuyvPath,
};

const W: u32 = 320;
const H: u32 = 240;

/// A known pattern per format, and the bytes it must arrive as.
fn pattern(format: PixelFormat) -> (Pattern, Vec<u8>) {
    let (w, h) = (W as usize, H as usize);
    let mut conv = Converter::new(W, H, format, YuyvPath::Simd);
    let mut expected = vec![0u8; w * h * format.bytes_per_pixel()];
    let p = match format {
        PixelFormat::Grey => {
            let g: Vec<u8> = (0..w * h).map(|i| ((i % w) + (i / w) * 3) as u8).collect();
            conv.grey8(Src::packed(&g, w, h, 1), &mut expected).unwrap();
            Pattern::Grey8(g)
        }
        PixelFormat::Y16 => {
            // signed difference ramp -3000..+3000 DN plus a row term
            let d: Vec<f32> = (0..w * h)
                .map(|i| (i % w) as f32 * 18.75 - 3000.0 + (i / w) as f32)
                .collect();
            conv.signed_dn(Src::packed(&d, w, h, 1), &mut expected)
                .unwrap();
            // independent check of the documented mapping: y16 = dn + 32768
            assert_eq!(u16::from_le_bytes([expected[0], expected[1]]), 32768 - 3000);
            Pattern::SignedDn(d)
        }
        PixelFormat::Yuyv | PixelFormat::Rgb24 => {
            let c: Vec<u8> = (0..w * h * 3).map(|i| ((i * 7) % 251) as u8).collect();
            conv.rgb8(Src::packed(&c, w, h, 3), &mut expected).unwrap();
            Pattern::Rgb8(c)
        }
    };
    (p, expected)
}

struct Node {
    nr: u32,
    label: &'static str,
}

const NODES: [Node; 6] = [
    Node {
        nr: 20,
        label: "sdi-grey",
    },
    Node {
        nr: 21,
        label: "sdi-y16",
    },
    Node {
        nr: 22,
        label: "sdi-yuyv",
    },
    Node {
        nr: 23,
        label: "sdi-rgb",
    },
    Node {
        nr: 24,
        label: "sdi-view",
    },
    Node {
        nr: 25,
        label: "ffmpeg-ref",
    },
];

fn dev(nr: u32) -> PathBuf {
    PathBuf::from(format!("/dev/video{nr}"))
}

/// ffmpeg reads 30 frames; every frame is either the pattern or the
/// "no signal" card, and the last one is the pattern, byte for byte.
fn check_round_trip(format: PixelFormat, nr: u32, io: IoMethod, reads: u32, tmp: &Path) {
    let cfg = OutputConfig {
        width: W,
        height: H,
        format,
        fps: 30,
        io,
    };
    let writer = LoopbackWriter::open(dev(nr), cfg).unwrap();
    assert_eq!(writer.io_method(), io, "{format}: io method");
    let card = writer.no_signal_frame().to_vec();
    let (pat, expected) = pattern(format);
    let bg = BackgroundWriter::start(writer, pat);
    let out = tmp.join(format!("{format}.raw"));
    // readers coming and going: the writer must not notice
    for round in 0..reads {
        let data = loopback::ffmpeg_read(&dev(nr), &cfg, 30, &out).unwrap();
        let n = cfg.frame_bytes();
        assert_eq!(
            data.len(),
            30 * n,
            "{format}: 30 frames of {n} bytes (round {round})"
        );
        for (i, frame) in data.chunks_exact(n).enumerate() {
            assert!(
                frame == expected || frame == card,
                "{format}: frame {i} is neither pattern nor card"
            );
        }
        assert!(
            data[29 * n..] == expected[..],
            "{format}: last frame differs from the pattern"
        );
    }
    let frames = bg.stop().unwrap();
    eprintln!("ok: {format} via {io:?}: {reads}x30 frames read back byte-exact ({frames} written)");
}

fn in_vm_checks() {
    // 1. module absent: a typed error naming the modprobe command
    match find_device("sdi-view") {
        Err(GlueError::ModuleNotLoaded { modprobe }) => {
            assert!(modprobe.contains("modprobe v4l2loopback") && modprobe.contains("sdi-view"))
        }
        other => panic!("expected ModuleNotLoaded, got {other:?}"),
    }
    let nodes: Vec<(u32, &str)> = NODES.iter().map(|n| (n.nr, n.label)).collect();
    loopback::modprobe(&nodes);
    let tmp = PathBuf::from("/tmp/sdi-loopback");
    std::fs::create_dir_all(&tmp).unwrap();

    // 2. lookup by card label + version
    let view = find_device("sdi-view").unwrap();
    assert_eq!(view.path, dev(24));
    eprintln!(
        "ok: find_device: {} on v4l2loopback {}",
        view.path.display(),
        view.version
    );
    assert!(matches!(
        find_device("nope"),
        Err(GlueError::DeviceNotFound { .. })
    ));

    // 3. exclusive_caps: output-only until we stream
    assert!(
        !loopback::advertises_capture(&view.path),
        "capture advertised before a producer"
    );

    // 4. pixel round trip per format (GREY/Y16 via mmap streaming, YUYV/RGB24 via write())
    check_round_trip(PixelFormat::Grey, 20, IoMethod::Mmap, 1, &tmp);
    check_round_trip(PixelFormat::Y16, 21, IoMethod::Mmap, 1, &tmp);
    check_round_trip(PixelFormat::Yuyv, 22, IoMethod::Write, 2, &tmp);
    check_round_trip(PixelFormat::Rgb24, 23, IoMethod::Write, 1, &tmp);

    // 5. the view profile, streaming, for the remaining clients
    let mut writer = LoopbackWriter::open(&view.path, OutputConfig::view(30)).unwrap();
    eprintln!("ok: view writer features: {:?}", writer.features());
    assert!(writer.features().keep_format && writer.features().sustain_framerate);
    assert!(writer.features().frame_interval);
    // 0.12.x has no client-usage event: "unsupported"
    let readers = writer.readers_present();
    if view.version.has_client_usage_event() {
        assert_eq!(readers, Some(false));
    } else {
        assert_eq!(readers, None, "0.12.x cannot report readers");
        eprintln!(
            "ok: readers_present() = None (unsupported on {})",
            view.version
        );
    }
    let rgb: Vec<u8> = (0..640 * 480 * 3).map(|i| (i % 253) as u8).collect();
    writer.write_rgb8(&rgb, 5_000_000).unwrap();
    assert!(
        loopback::advertises_capture(&view.path),
        "capture not advertised while streaming"
    );
    eprintln!("ok: exclusive_caps: capture advertised only while streaming");

    // 6. a second producer asking for another format gets a typed error
    let other = OutputConfig {
        format: PixelFormat::Grey,
        ..OutputConfig::view(30)
    };
    match LoopbackWriter::open(&view.path, other) {
        Err(GlueError::FormatLocked { wanted, current }) => {
            eprintln!("ok: format change refused: wanted {wanted}, locked to {current}")
        }
        Err(GlueError::Busy { .. }) => eprintln!("ok: format change refused: EBUSY"),
        other => panic!("expected FormatLocked, got {:?}", other.map(|w| w.config())),
    }
    let bg = BackgroundWriter::start(writer, Pattern::Rgb8(rgb));

    // 7. OpenCV reads frames of the expected size
    let py = "import cv2,sys\n\
              cap=cv2.VideoCapture(sys.argv[1], cv2.CAP_V4L2)\n\
              assert cap.isOpened(), 'not opened'\n\
              shapes=set()\n\
              for _ in range(10):\n\
              \x20   ok,f=cap.read()\n\
              \x20   assert ok, 'read failed'\n\
              \x20   shapes.add(f.shape)\n\
              print(sorted(shapes))\n";
    let o = Command::new("timeout")
        .args(["60", "/usr/bin/python3", "-c", py, "/dev/video24"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "OpenCV failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(text.trim(), "[(480, 640, 3)]", "OpenCV frame shapes");
    eprintln!("ok: OpenCV read 10 frames of 640x480x3");

    // 8. v4l2-compliance with our writer vs ffmpeg as the writer
    let ours = loopback::compliance(&view.path).unwrap();
    let frames = bg.stop().unwrap();
    let mut ff = Command::new("ffmpeg")
        .args([
            "-hide_banner",
            "-loglevel",
            "error",
            "-nostdin",
            "-re",
            "-f",
            "lavfi",
        ])
        .args([
            "-i",
            "testsrc=size=640x480:rate=30",
            "-pix_fmt",
            "yuyv422",
            "-f",
            "v4l2",
            "/dev/video25",
        ])
        .spawn()
        .unwrap();
    let ready = (0..300).any(|_| {
        std::thread::sleep(std::time::Duration::from_millis(100));
        loopback::advertises_capture(&dev(25))
    });
    let reference = loopback::compliance(&dev(25));
    let _ = ff.kill();
    let _ = ff.wait();
    assert!(ready, "ffmpeg writer never made /dev/video25 capture-ready");
    let reference = reference.unwrap();
    for (who, c) in [("SDI writer", &ours), ("ffmpeg writer", &reference)] {
        eprintln!(
            "compliance {who}: total {} succeeded {} failed {} warnings {}; failing: {:?}",
            c.total, c.succeeded, c.failed, c.warnings, c.failing_tests
        );
    }
    std::fs::write(tmp.join("compliance-ours.txt"), &ours.output).unwrap();
    if let Ok(dir) = std::env::var("SDI_VM_OUT") {
        let _ = std::fs::write(Path::new(&dir).join("compliance-ours.txt"), &ours.output);
        let _ = std::fs::write(
            Path::new(&dir).join("compliance-ffmpeg.txt"),
            &reference.output,
        );
    }
    assert!(
        ours.total > 0 && ours.failed <= reference.failed,
        "SDI writer fails more compliance tests than ffmpeg"
    );
    assert!(
        ours.failed <= 5,
        "more than the 5 known driver-side failures"
    );
    eprintln!("ok: view writer streamed {frames} frames through OpenCV + compliance");
}

#[test]
fn vm_loopback_end_to_end() {
    if !vm::in_vm() {
        vm::run_test_in_vm("vm_loopback_end_to_end", 900);
        return;
    }
    in_vm_checks();
}

/// The harness swaps module builds inside the VM: 0.15.0 from setup-host.sh's
/// out-of-tree build, then back to Debian's 0.12.7.
fn module_switch_checks() {
    use loopback::{ModuleBuild, ModuleParams};
    loopback::load_module(ModuleBuild::V0150, &ModuleParams::nodes(&[(30, "sdi-v15")]))
        .unwrap_or_else(|e| panic!("{e}"));
    let v15 = find_device("sdi-v15").unwrap();
    assert_eq!(v15.path, dev(30));
    assert_eq!(v15.version.to_string(), "0.15.0");
    assert!(
        Path::new("/dev/v4l2loopback").exists(),
        "0.15 control device"
    );
    eprintln!("ok: loaded {}: {}", ModuleBuild::V0150, v15.path.display());
    loopback::load_module(
        ModuleBuild::Debian0127,
        &ModuleParams::nodes(&[(31, "sdi-v12")]),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let v12 = find_device("sdi-v12").unwrap();
    assert!(v12.version < v4l2loopback_glue::ModuleVersion::parse("0.13").unwrap());
    assert!(
        !Path::new("/dev/v4l2loopback").exists(),
        "0.12.7 has no control device"
    );
    loopback::unload_module().unwrap_or_else(|e| panic!("{e}"));
    eprintln!("ok: back to {} ({})", ModuleBuild::Debian0127, v12.version);
}

#[test]
fn vm_loopback_module_switch() {
    if !vm::in_vm() {
        vm::run_test_in_vm("vm_loopback_module_switch", 300);
        return;
    }
    module_switch_checks();
}
