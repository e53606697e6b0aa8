//! End-to-end: the glue publishes simulator frames on v4l2loopback inside
//! the VM and real clients (ffmpeg, v4l2-ctl, v4l2-compliance, OpenCV) read
//! them, on Debian's 0.12.7 and on 0.15.0, in one VM boot.

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use sdi_tests::loopback::{self, BackgroundWriter, Compliance, ModuleBuild, ModuleParams};
use sdi_tests::sim_frames::{checksum, SimFrames};
use v4l2loopback_glue::{
    control_version, create_device, driver_of, find_device, query_device, remove_device,
    CaptureReader, CreateOptions, GlueError, IoMethod, LoopbackFormat, LoopbackWriter,
    ModuleVersion, PixelFormat,
};

/// The TI OPT8241 model's size: the simulator frames are published as is.
const W: u32 = 320;
const H: u32 = 240;
/// Distinct simulator frames the writers cycle through.
const SIM_FRAMES: usize = 12;

/// The module's ring (default 2): see `DriverFeatures::buffers`. ffmpeg's
/// capture keeps up to 7/8 of the ring as zero-copy packets, and the writer
/// refills a buffer one ring later whatever the reader holds: under TCG
/// load ffmpeg's start-up lagged more than 8 frames at 30 fps (one torn
/// frame in four runs), so the round trips run at 15 fps (10 buffers:
/// 0.67 s of slack). OpenCV copes with at most 10.
const MAX_BUFFERS: u32 = 10;
const ROUND_TRIP_FPS: u32 = 15;
/// Frames each reader of a round trip takes: more than the writer's ring
/// (4 buffers on 0.12.x, 10 on 0.15), so buffers are refilled under the
/// reader, and than the 12 distinct simulator frames. It was 30: at
/// 0.12.x's 5 fps the 20 reads of its round trips then waited about two
/// minutes of CI's longest VM lane.
const ROUND_FRAMES: usize = 15;

/// The writer's ring on the loaded module, and the round-trip rate that
/// gives readers the same 0.6 s of slack: 0.12.x gets a ring of 4 (see
/// `MMAP_BUFFERS_UNLOCKED_QUEUE` in the glue's writer), so 5 fps there.
fn ring_and_fps() -> (u32, u32) {
    let locked =
        ModuleVersion::of_loaded_module().is_ok_and(ModuleVersion::has_locked_buffer_queue);
    let ring = if locked { MAX_BUFFERS } else { 4 };
    (ring, ROUND_TRIP_FPS * (ring - 1) / (MAX_BUFFERS - 1))
}

const NODES: [(u32, &str); 6] = [
    (20, "sdi-grey"),
    (21, "sdi-y16"),
    (22, "sdi-yuyv"),
    (23, "sdi-rgb"),
    (24, "sdi-view"),
    (25, "ffmpeg-ref"),
];

/// v4l2-compliance failures of our writer per module, of 45 tests, each
/// explained in docs/loopback.md (ffmpeg's writer, the reference, fails
/// at least these).
fn expected_failures(build: ModuleBuild) -> Option<u32> {
    match build {
        ModuleBuild::Debian0127 => Some(5),
        ModuleBuild::V0150 => Some(1),
    }
}

/// v4l2-compliance's buffer test, which 0.15 fails by a race of the module.
const QUERYBUF_TEST: &str = "test VIDIOC_REQBUFS/CREATE_BUFS/QUERYBUF: FAIL";
/// Its check that an unqueued buffer has sequence 0: the one that races.
const SEQUENCE_CHECK: &str = "v4l2-test-buffers.cpp(452): g_sequence()";

/// `c` without the failure v4l2loopback 0.15 gives any live writer now and
/// then: the capture side's QUERYBUF shows the sequence the writer gave a
/// buffer, so an unqueued buffer's `g_sequence()` is not 0 when the writer
/// filled that buffer just before the query. Seen with ffmpeg as the writer
/// and with ours (CI of d52b2ea: ours 2 failures, ffmpeg's 1, the extra one
/// this check), never on 0.12.7. Only that test is taken out, and only
/// when that check is among the reasons v4l2-compliance gives.
fn without_sequence_race(build: ModuleBuild, mut c: Compliance) -> Compliance {
    let raced = build == ModuleBuild::V0150
        && c.failing_tests.iter().any(|t| t == QUERYBUF_TEST)
        && c.fail_reasons.iter().any(|r| r.ends_with(SEQUENCE_CHECK));
    if raced {
        c.failing_tests.retain(|t| t != QUERYBUF_TEST);
        c.failed -= 1;
        eprintln!("note: {build}: QUERYBUF failed on the module's sequence race ({SEQUENCE_CHECK}); not counted");
    }
    c
}

fn dev(nr: u32) -> PathBuf {
    PathBuf::from(format!("/dev/video{nr}"))
}

/// ffmpeg reads [`ROUND_FRAMES`] frames per round; every frame must be byte for byte one
/// of the simulator frames written (by checksum) or the "no signal" card,
/// several distinct simulator frames must arrive, and the last frame is a
/// simulator frame. Changing frames catch torn or stale buffers.
fn check_round_trip(
    sim: &SimFrames,
    format: PixelFormat,
    nr: u32,
    io: IoMethod,
    reads: u32,
    tmp: &Path,
) {
    let (ring, fps) = ring_and_fps();
    let cfg = LoopbackFormat {
        width: W,
        height: H,
        format,
        fps,
        io,
    };
    let writer = LoopbackWriter::open(dev(nr), cfg).unwrap();
    assert_eq!(writer.io_method(), io, "{format}: io method");
    if io == IoMethod::Mmap {
        assert_eq!(writer.features().buffers, ring, "{format}: ring");
    }
    let card = checksum(writer.no_signal_frame());
    let expected = sim.patterns(format);
    let patterns = expected.clone();
    let index: HashMap<u64, usize> = expected
        .iter()
        .enumerate()
        .map(|(k, e)| (checksum(e), k))
        .collect();
    assert_eq!(index.len(), SIM_FRAMES, "{format}: simulator frames differ");
    let bg = BackgroundWriter::start(writer, patterns);
    let out = tmp.join(format!("{format}.raw"));
    let n = cfg.frame_bytes();
    let check = |data: &[u8], reader: &str, round: u32| {
        assert_eq!(
            data.len(),
            ROUND_FRAMES * n,
            "{format}: {ROUND_FRAMES} frames ({reader}, round {round})"
        );
        let mut seen = BTreeSet::new();
        let mut cards = 0;
        for (i, frame) in data.chunks_exact(n).enumerate() {
            let sum = checksum(frame);
            match index.get(&sum) {
                Some(k) => {
                    seen.insert(*k);
                }
                None if sum == card => cards += 1,
                None => panic!(
                    "{format} via {io:?}, {reader}: frame {i} (checksum {sum:016x}) is neither \
                     a simulator frame written nor the card"
                ),
            }
        }
        assert!(
            seen.len() >= 3,
            "{format}, {reader}: only simulator frames {seen:?} arrived"
        );
        assert!(
            index.contains_key(&checksum(&data[(ROUND_FRAMES - 1) * n..])),
            "{format}, {reader}: last frame is not a simulator frame"
        );
        (seen, cards)
    };
    // readers coming and going: the writer must not notice
    for round in 0..reads {
        let t0 = std::time::Instant::now();
        let data = loopback::ffmpeg_read(&dev(nr), &cfg, ROUND_FRAMES as u32, &out).unwrap();
        let (seen, cards) = check(&data, "ffmpeg", round);
        eprintln!(
            "ok: {format} via {io:?}: {ROUND_FRAMES} frames in {:.1} s, byte-exact; {} distinct simulator \
             frames {seen:?}, {cards} no-signal cards",
            t0.elapsed().as_secs_f64(),
            seen.len()
        );
    }
    // and a Rust client (the glue's CaptureReader), mmap streaming
    let t0 = std::time::Instant::now();
    let data = v4l_read(&dev(nr), &cfg, ROUND_FRAMES);
    let (seen, cards) = check(&data, "v4l", 0);
    eprintln!(
        "ok: {format} via {io:?}: v4l client, {ROUND_FRAMES} frames in {:.1} s, byte-exact; {} distinct \
         simulator frames, {cards} no-signal cards",
        t0.elapsed().as_secs_f64(),
        seen.len()
    );
    let frames = bg.stop().unwrap();
    eprintln!("ok: {format} via {io:?}: {reads} reader(s), {frames} frames written");
}

/// Reads `frames` frames from `path` as a capture application does
/// (VIDIOC_G_FMT, mmap streaming), after checking that the node announces
/// `cfg`'s format.
fn v4l_read(path: &Path, cfg: &LoopbackFormat, frames: usize) -> Vec<u8> {
    assert_eq!(
        driver_of(path).unwrap(),
        "v4l2 loopback",
        "{}",
        path.display()
    );
    let mut stream = CaptureReader::open(path, 4).unwrap();
    let fmt = stream.format().unwrap();
    assert_eq!(
        (fmt.width, fmt.height, fmt.fourcc),
        (cfg.width, cfg.height, cfg.format.fourcc()),
        "{}: capture format",
        path.display()
    );
    let n = cfg.frame_bytes();
    let mut data = Vec::with_capacity(frames * n);
    for i in 0..frames {
        let frame = stream.next(Duration::from_secs(10)).unwrap();
        assert_eq!(frame.bytes.len(), n, "{}: frame {i} size", path.display());
        data.extend_from_slice(frame.bytes);
    }
    data
}

/// A reader that asks for 2 buffers shrinks the module's ring for everyone
/// (`used_buffers`, 0.12.7 and 0.15 alike), and the writer must still
/// publish each new frame (docs/loopback.md: before the fix it filled its
/// own mapping of buffer i while the module marked buffer i % 2, so readers
/// got frames up to 10 old). The writer stamps a counter into each frame;
/// the module hands a reader at most `used_buffers` (2) frames behind the
/// newest, or the previous one again when it re-sends (sustain_framerate).
/// So every dequeued counter is >= the one before and at most 2 behind the
/// newest frame written before the reader asked: exact, whatever the load.
/// The writer holds still while the reader's REQBUFS shrinks the ring:
/// 0.12.7 unlinks buffers there without its lock, and a QBUF in that window
/// is a kernel BUG (see `MMAP_BUFFERS_UNLOCKED_QUEUE` in the glue).
fn check_small_reader_ring(nr: u32) {
    use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
    use std::sync::Arc;
    let cfg = LoopbackFormat {
        width: W,
        height: H,
        format: PixelFormat::Grey,
        fps: 30,
        io: IoMethod::Mmap,
    };
    let mut writer = LoopbackWriter::open(dev(nr), cfg).unwrap();
    let (written, stop) = (
        Arc::new(AtomicU32::new(0)),
        Arc::new(AtomicBool::new(false)),
    );
    // hold: asked to pause; held: the writer is between frames, paused.
    let (hold, held) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicBool::new(false)),
    );
    let bg = {
        let (written, stop) = (Arc::clone(&written), Arc::clone(&stop));
        let (hold, held) = (Arc::clone(&hold), Arc::clone(&held));
        std::thread::spawn(move || {
            let mut frame = vec![0u8; cfg.frame_bytes()];
            for k in 1u32.. {
                while hold.load(Ordering::SeqCst) && !stop.load(Ordering::SeqCst) {
                    held.store(true, Ordering::SeqCst);
                    std::thread::sleep(Duration::from_millis(5));
                }
                held.store(false, Ordering::SeqCst);
                if stop.load(Ordering::SeqCst) {
                    break;
                }
                frame[..4].copy_from_slice(&k.to_le_bytes());
                writer.write(&frame, u64::from(k) * 33_333).unwrap();
                written.store(k, Ordering::SeqCst);
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };
    let t0 = std::time::Instant::now();
    while !loopback::advertises_capture(&dev(nr)) {
        assert!(t0.elapsed() < Duration::from_secs(10), "no capture side");
        std::thread::sleep(Duration::from_millis(50));
    }
    hold.store(true, Ordering::SeqCst);
    while !held.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut stream = CaptureReader::open(&dev(nr), 2).unwrap();
    hold.store(false, Ordering::SeqCst);
    let (mut last, mut max_lag) = (0u32, 0u32);
    for i in 0..60 {
        let newest = written.load(Ordering::SeqCst);
        let buf = stream.next(Duration::from_secs(10)).unwrap().bytes;
        let got = u32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]);
        assert!(got >= last, "frame {i}: counter {got} after {last}");
        if i > 0 {
            assert!(
                got + 2 >= newest,
                "frame {i}: counter {got}, but {newest} was written before the reader asked"
            );
            max_lag = max_lag.max(newest.saturating_sub(got));
        }
        last = got;
    }
    drop(stream);
    stop.store(true, Ordering::SeqCst);
    bg.join().unwrap();
    eprintln!("ok: 2-buffer reader: 60 frames in order, at most {max_lag} behind the writer");
}

/// sdid restarted with another geometry on a node (another sensor or ROI:
/// the data node's size): the earlier producer's `keep_format` must not
/// pin the node once nobody holds it (before, the new producer got
/// FormatLocked until the module was reloaded). While a reader holds the
/// node, the new geometry is refused and the node keeps the reader's
/// format, still pinned. Node `nr` last had Grey at the simulator's size,
/// written over mmap as sdid writes (`check_small_reader_ring`), its
/// producer gone. (After a producer that used write(), 0.12.7 never
/// announces output again, whatever the format: its close marks only mmap
/// writers as gone.)
fn check_new_geometry(nr: u32) {
    let (_, fps) = ring_and_fps();
    let small = LoopbackFormat {
        width: 64,
        height: 48,
        format: PixelFormat::Y16,
        fps,
        io: IoMethod::Mmap,
    };
    let writer = LoopbackWriter::open(dev(nr), small)
        .unwrap_or_else(|e| panic!("video{nr}: a new geometry once its producer left: {e}"));
    assert_eq!(writer.config(), small);
    let bg = BackgroundWriter::start(writer, vec![vec![7u8; small.frame_bytes()]]);
    let mut reader = CaptureReader::open(&dev(nr), 4).expect("a capture reader");
    let n = reader
        .next(Duration::from_secs(10))
        .expect("a frame")
        .bytes
        .len();
    assert_eq!(
        n,
        small.frame_bytes(),
        "video{nr}: the new geometry's frame"
    );
    bg.stop().expect("the writer");
    // The reader still streams: the producer's old geometry stays for it.
    let big = LoopbackFormat {
        width: W,
        height: H,
        ..small
    };
    match LoopbackWriter::open(dev(nr), big) {
        Err(GlueError::FormatLocked { .. } | GlueError::Busy { .. }) => {}
        other => panic!(
            "video{nr}: another geometry under a streaming reader: {:?}",
            other.map(|w| w.config())
        ),
    }
    let o = Command::new("v4l2-ctl")
        .args(["-d", &dev(nr).display().to_string(), "-C", "keep_format"])
        .output()
        .expect("run v4l2-ctl");
    let pinned = String::from_utf8_lossy(&o.stdout).trim().to_owned();
    assert_eq!(
        pinned, "keep_format: 1",
        "video{nr}: not pinned again for the reader"
    );
    let again = LoopbackWriter::open(dev(nr), small)
        .unwrap_or_else(|e| panic!("video{nr}: the reader's geometry again: {e}"));
    drop(again);
    drop(reader);
    eprintln!(
        "ok: video{nr}: a new geometry once its producer left; refused under a streaming \
         reader, which keeps its format (keep_format pinned again)"
    );
}

/// ffmpeg reading `node` until killed, frames discarded.
fn ffmpeg_reader(node: &str) -> Vec<&str> {
    vec![
        "ffmpeg",
        "-hide_banner",
        "-loglevel",
        "error",
        "-nostdin",
        "-f",
        "v4l2",
        "-i",
        node,
        "-f",
        "null",
        "-",
    ]
}

/// A capture reader that streams until killed.
fn spawn_reader(args: &[&str]) -> Child {
    Command::new(args[0])
        .args(&args[1..])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("spawn {}: {e}", args[0]))
}

fn stop(mut child: Child) {
    let _ = child.kill();
    let _ = child.wait();
}

/// The client-usage event: 0 without readers, 1 while ffmpeg or v4l2-ctl
/// stream (0.15 reports "a reader holds the capture stream", not a count),
/// back to 0 when they exit; `None` on 0.12.x.
fn check_watchers(bg: &BackgroundWriter, version: ModuleVersion, node: &str) {
    let wait = |want| bg.wait_watchers(want, Duration::from_secs(30));
    if !version.has_client_usage_event() {
        assert_eq!(bg.watchers(), None, "0.12.x cannot report readers");
        eprintln!("ok: watchers() = None (no client-usage event in {version})");
        return;
    }
    assert_eq!(wait(Some(0)), Some(0), "nobody watches yet");
    let readers: [Vec<&str>; 2] = [
        ffmpeg_reader(node),
        vec![
            "v4l2-ctl",
            "-d",
            node,
            "--stream-mmap",
            "--stream-count=100000",
        ],
    ];
    for argv in &readers {
        let reader = spawn_reader(argv);
        let seen = wait(Some(1));
        stop(reader);
        assert_eq!(seen, Some(1), "{} streaming: watchers", argv[0]);
        assert_eq!(wait(Some(0)), Some(0), "{} gone: watchers", argv[0]);
        eprintln!("ok: watchers() 0 -> 1 -> 0 around a {} reader", argv[0]);
    }
}

/// 0.13+: the control device creates, queries and removes nodes; 0.15 has
/// the VERSION ioctl.
fn check_control_device(version: ModuleVersion) {
    if !version.has_control_device() {
        assert!(matches!(
            create_device(&CreateOptions::new("sdi-created")),
            Err(GlueError::Unsupported { .. })
        ));
        assert!(matches!(
            query_device(20),
            Err(GlueError::Unsupported { .. })
        ));
        eprintln!("ok: {version}: create/query refused as Unsupported");
        return;
    }
    if version.has_new_control_ioctls() {
        assert_eq!(control_version().unwrap(), version, "VERSION ioctl");
    }
    let info = query_device(24).unwrap();
    assert_eq!(info.label, "sdi-view");
    assert!(!info.announce_all_caps, "exclusive_caps node");
    let opts = CreateOptions {
        video_nr: Some(50),
        ..CreateOptions::new("sdi-created")
    };
    let created = create_device(&opts).unwrap();
    assert_eq!(created.path, dev(50));
    assert_eq!(find_device("sdi-created").unwrap().path, dev(50));
    let created_info = query_device(50).unwrap();
    assert_eq!(created_info.label, "sdi-created");
    assert_eq!(created_info.max_buffers, opts.max_buffers as i32);
    // again: found, not created twice
    assert_eq!(create_device(&opts).unwrap().path, dev(50));
    {
        let _open = LoopbackWriter::open(&created.path, LoopbackFormat::raw(64, 48, 10)).unwrap();
        assert!(
            matches!(remove_device(&created), Err(GlueError::Busy { .. })),
            "REMOVE of an open node"
        );
    }
    remove_device(&created).unwrap();
    assert!(matches!(
        find_device("sdi-created"),
        Err(GlueError::DeviceNotFound { .. })
    ));
    assert!(query_device(50).is_err());
    eprintln!("ok: {version}: control device ADD/QUERY/REMOVE (+ VERSION), EBUSY while open");
}

fn compliance_of_ffmpeg_writer(nr: u32) -> Compliance {
    let mut ff = Command::new("ffmpeg")
        .args(["-hide_banner", "-loglevel", "error", "-nostdin", "-re"])
        .args(["-f", "lavfi", "-i", "testsrc=size=640x480:rate=30"])
        .args(["-pix_fmt", "yuyv422", "-f", "v4l2"])
        .arg(dev(nr))
        .spawn()
        .unwrap();
    let ready = (0..300).any(|_| {
        std::thread::sleep(Duration::from_millis(100));
        loopback::advertises_capture(&dev(nr))
    });
    let reference = loopback::compliance(&dev(nr));
    let _ = ff.kill();
    let _ = ff.wait();
    assert!(
        ready,
        "ffmpeg writer never made /dev/video{nr} capture-ready"
    );
    reference.unwrap()
}

fn module_checks(build: ModuleBuild, sim: &SimFrames, tmp: &Path) {
    let params = ModuleParams {
        extra: vec![format!("max_buffers={MAX_BUFFERS}")],
        ..ModuleParams::nodes(&NODES)
    };
    loopback::load_module(build, &params).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("== {build}");

    // lookup by card label + version
    let view = find_device("sdi-view").unwrap();
    assert_eq!(view.path, dev(24));
    if let Some(v) = build.version() {
        assert_eq!(view.version.to_string(), v);
    }
    assert!(matches!(
        find_device("nope"),
        Err(GlueError::DeviceNotFound { .. })
    ));
    check_control_device(view.version);

    // exclusive_caps: output-only until we stream
    assert!(
        !loopback::advertises_capture(&view.path),
        "capture advertised before a producer"
    );

    // simulator frames, every format, mmap streaming (two readers one
    // after the other) and write()
    for (format, nr) in [
        (PixelFormat::Grey, 20),
        (PixelFormat::Y16, 21),
        (PixelFormat::Yuyv, 22),
        (PixelFormat::Rgb24, 23),
    ] {
        check_round_trip(sim, format, nr, IoMethod::Mmap, 2, tmp);
        check_round_trip(sim, format, nr, IoMethod::Write, 1, tmp);
    }
    check_small_reader_ring(20);
    check_new_geometry(20);

    // the view profile, streaming, for the remaining clients
    let mut writer = LoopbackWriter::open(&view.path, LoopbackFormat::view(30)).unwrap();
    eprintln!("ok: view writer features: {:?}", writer.features());
    let f = writer.features();
    // sustain_framerate: the module has the control, and the writer keeps
    // it off (a repeat re-hands readers a buffer they may hold).
    assert!(f.keep_format && !f.sustain_framerate && f.frame_interval);
    assert!(
        writer.set_sustain_framerate(false),
        "no sustain_framerate control"
    );
    assert_eq!(f.client_usage_event, view.version.has_client_usage_event());
    let mut rgb = vec![0u8; 640 * 480 * 3];
    sdi_core::view::letterbox_rgb8(&sim_rgb(sim), W as usize, H as usize, &mut rgb, 640, 480);
    let view_cfg = writer.config();
    let mut packed = vec![0u8; view_cfg.frame_bytes()];
    sdi_core::view::Packer::new(640, 480, view_cfg.format)
        .rgb8(sdi_core::view::Src::packed(&rgb, 640, 480, 3), &mut packed)
        .expect("pack the view frame");
    let bg = BackgroundWriter::start(writer, vec![packed]);
    let capture_ready = (0..100).any(|_| {
        std::thread::sleep(Duration::from_millis(50));
        loopback::advertises_capture(&view.path)
    });
    assert!(capture_ready, "capture not advertised while streaming");
    eprintln!("ok: exclusive_caps: capture advertised only while streaming");
    check_watchers(&bg, view.version, "/dev/video24");

    // a second producer asking for another format gets a typed error
    let other = LoopbackFormat {
        format: PixelFormat::Grey,
        ..LoopbackFormat::view(30)
    };
    match LoopbackWriter::open(&view.path, other) {
        Err(GlueError::FormatLocked { wanted, current }) => {
            eprintln!("ok: format change refused: wanted {wanted}, locked to {current}")
        }
        Err(GlueError::Busy { .. }) => eprintln!("ok: format change refused: EBUSY"),
        other => panic!("expected FormatLocked, got {:?}", other.map(|w| w.config())),
    }

    // OpenCV reads frames of the expected size
    let py = "import cv2,sys\n\
              cap=cv2.VideoCapture(sys.argv[1], cv2.CAP_V4L2)\n\
              assert cap.isOpened(), 'not opened'\n\
              shapes=set()\n\
              for _ in range(10):\n\
              \x20   ok,f=cap.read()\n\
              \x20   assert ok, 'read failed'\n\
              \x20   shapes.add(f.shape)\n\
              print(sorted(shapes))\n";
    // The limit only catches a hang: importing cv2 alone takes tens of
    // seconds in a TCG guest beside a busy host.
    let o = Command::new("timeout")
        .args(["300", "/usr/bin/python3", "-c", py, "/dev/video24"])
        .output()
        .unwrap();
    // OpenCV indexes a fixed array of 10 buffers: the writer's ring must
    // not be larger (it aborted on a 32-buffer ring on 0.15).
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success(),
        "OpenCV failed ({}; 124 = killed at the limit): {stderr}",
        o.status
    );
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        "[(480, 640, 3)]",
        "OpenCV frame shapes"
    );
    eprintln!("ok: OpenCV read 10 frames of 640x480x3");

    // v4l2-compliance with our writer vs ffmpeg as the writer
    let ours = loopback::compliance(&view.path).unwrap();
    let frames = bg.stop().unwrap();
    let reference = compliance_of_ffmpeg_writer(25);
    for (who, c) in [("SDI writer", &ours), ("ffmpeg writer", &reference)] {
        eprintln!(
            "compliance {build} {who}: total {} succeeded {} failed {} warnings {}; failing: {:?}",
            c.total, c.succeeded, c.failed, c.warnings, c.failing_tests
        );
        for reason in &c.fail_reasons {
            eprintln!("    {reason}");
        }
    }
    if let Ok(dir) = std::env::var("SDI_VM_OUT") {
        let tag = build.version().unwrap_or("0.12.7");
        let _ = std::fs::write(
            Path::new(&dir).join(format!("compliance-ours-{tag}.txt")),
            &ours.output,
        );
        let _ = std::fs::write(
            Path::new(&dir).join(format!("compliance-ffmpeg-{tag}.txt")),
            &reference.output,
        );
    }
    // The module's sequence race is no writer's failure: it is taken out
    // of both counts. Everything else of ours is pinned: a new failure of
    // our writer must show.
    let ours = without_sequence_race(build, ours);
    let reference = without_sequence_race(build, reference);
    assert!(
        ours.total > 0 && ours.failed <= reference.failed,
        "SDI writer fails more than ffmpeg's"
    );
    for t in &ours.failing_tests {
        assert!(
            reference.failing_tests.contains(t),
            "{build}: our writer fails {t}, ffmpeg's does not"
        );
    }
    if let Some(want) = expected_failures(build) {
        assert_eq!(
            ours.failed, want,
            "{build}: v4l2-compliance failures of our writer"
        );
    }
    eprintln!("ok: view writer streamed {frames} frames through OpenCV + compliance");
    check_daemon_output(view.version);
}

/// The daemon's output thread over its v4l2loopback sink reports the
/// readers the frame loop uses to switch the light sources off.
fn check_daemon_output(version: ModuleVersion) {
    use sdi_daemon::sink::{loopback::LoopbackSink, output::Output};
    let sink = LoopbackSink::open("sdi-view", "", W as usize, H as usize, 30.0).unwrap();
    let output = Output::spawn(Box::new(sink)).unwrap();
    let wait = |want: Option<u32>| {
        let t0 = std::time::Instant::now();
        while output.watchers() != want && t0.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(50));
        }
        output.watchers()
    };
    if !version.has_client_usage_event() {
        std::thread::sleep(Duration::from_millis(500));
        assert_eq!(output.watchers(), None, "0.12.x: unknown, lights stay on");
        eprintln!("ok: daemon Output::watchers() = None on {version}");
        return;
    }
    assert_eq!(wait(Some(0)), Some(0), "daemon output: nobody watches");
    let reader = spawn_reader(&ffmpeg_reader("/dev/video24"));
    let seen = wait(Some(1));
    stop(reader);
    assert_eq!(seen, Some(1), "daemon output: ffmpeg watching");
    assert_eq!(wait(Some(0)), Some(0), "daemon output: ffmpeg gone");
    eprintln!("ok: daemon Output::watchers() 0 -> 1 -> 0 around an ffmpeg reader");
}

/// The first simulator frame through the display mapping, RGB8.
fn sim_rgb(sim: &SimFrames) -> Vec<u8> {
    sim.patterns(PixelFormat::Rgb24).swap_remove(0)
}

fn in_vm_checks() {
    // module absent: a typed error naming the modprobe command
    loopback::unload_module().unwrap_or_else(|e| panic!("{e}"));
    match find_device("sdi-view") {
        Err(GlueError::ModuleNotLoaded { modprobe }) => {
            assert!(modprobe.contains("modprobe v4l2loopback") && modprobe.contains("sdi-view"))
        }
        other => panic!("expected ModuleNotLoaded, got {other:?}"),
    }
    let tmp = PathBuf::from("/tmp/sdi-loopback");
    std::fs::create_dir_all(&tmp).unwrap();
    let sim = SimFrames::render(SIM_FRAMES, 7);
    assert_eq!((sim.width, sim.height), (W as usize, H as usize));
    for build in [ModuleBuild::Debian0127, ModuleBuild::V0150] {
        module_checks(build, &sim, &tmp);
    }
    loopback::unload_module().unwrap_or_else(|e| panic!("{e}"));
}

#[test]
fn vm_loopback_end_to_end() {
    if crate::GUEST.on_host() {
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
    if crate::GUEST.on_host() {
        return;
    }
    module_switch_checks();
}
