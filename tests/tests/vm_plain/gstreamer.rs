//! GStreamer's `v4l2src` on both SDI nodes, in the VM, with the real `sdid`
//! publishing: `gst-launch-1.0 v4l2src` negotiates YUY2 640x480 on the view
//! node and GRAY16_LE at the sensor size on the Y16 data node, and the
//! frames it reads show the mode: the view's letterbox bars are black, its
//! picture has the mean colour of `sdictl snapshot x.png`, and changes with
//! `sdictl set-mode`; the data node's mean (minus the 32768 offset) is the
//! mean DN of `sdictl snapshot x.npy`. The simulator runs the OPT8241
//! sensor (320x240): GStreamer 1.22 fails on the pmd sensor's 165-pixel
//! Y16 rows ("could not map buffer", docs/loopback.md).

use std::process::Command;
use std::time::Instant;

use sdi_tests::clients::{self, letterbox_rows, mean_rgb, Sdid, TI};

const VIEW_NR: u32 = 40;
const DATA_NR: u32 = 41;
const FRAMES: usize = 4;

/// `gst-launch-1.0 -v` with `pipeline`; returns (its log, seconds taken).
fn gst(pipeline: &str) -> (String, f64) {
    let t0 = Instant::now();
    let out = Command::new("timeout")
        .args(["120", "gst-launch-1.0", "-v"])
        .args(pipeline.split_whitespace())
        .env("GST_DEBUG", "v4l2*:3")
        .output()
        .expect("run gst-launch-1.0");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "gst-launch-1.0 {pipeline}: {}\n{log}",
        out.status
    );
    (log, t0.elapsed().as_secs_f64())
}

/// Reads FRAMES view frames as RGB; returns the last one.
fn read_view(sdid: &Sdid) -> Vec<u8> {
    let file = "/tmp/sdi-clients/view.rgb";
    let (log, secs) = gst(&format!(
        "v4l2src device={} num-buffers={FRAMES} ! video/x-raw,format=YUY2,width=640,height=480 \
         ! videoconvert ! video/x-raw,format=RGB ! filesink location={file}",
        sdid.view.display()
    ));
    assert!(
        log.contains("v4l2src0.GstPad:src: caps = video/x-raw, format=(string)YUY2, width=(int)640, height=(int)480"),
        "v4l2src did not negotiate YUY2 640x480:\n{log}"
    );
    let bytes = std::fs::read(file).expect("read view frames");
    assert_eq!(
        bytes.len(),
        FRAMES * 640 * 480 * 3,
        "view: {FRAMES} frames of 640x480 RGB"
    );
    eprintln!("gst view: {FRAMES} frames in {secs:.1} s (process start to EOS)");
    bytes[(FRAMES - 1) * 640 * 480 * 3..].to_vec()
}

/// Checks a view frame against the snapshot's mean colour; returns the picture's mean.
fn check_view(frame: &[u8], expected: [f64; 3], what: &str) -> [f64; 3] {
    let (bar, rows) = letterbox_rows(TI.width, TI.height);
    let row = 640 * 3;
    // The bars (if the sensor's aspect leaves any) are black (YUV -> RGB
    // by videoconvert: allow a few codes).
    if bar >= 2 {
        let top = mean_rgb(&frame[..(bar - 1) * row]);
        let bottom = mean_rgb(&frame[(bar + rows + 1) * row..]);
        for m in [top, bottom] {
            assert!(
                m.iter().all(|&c| c < 6.0),
                "{what}: letterbox bars not black: {m:?}"
            );
        }
    }
    let (first, last) = if bar >= 2 {
        (bar + 1, bar + rows - 1)
    } else {
        (0, 480)
    };
    let picture = mean_rgb(&frame[first * row..last * row]);
    let worst = picture
        .iter()
        .zip(expected)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    eprintln!("{what}: picture mean {picture:.1?}, snapshot {expected:.1?}, worst channel off by {worst:.1}");
    // YUYV subsampling, limited-range round trips, one frame vs another: 8 codes.
    assert!(
        worst < 8.0,
        "{what}: the view's colours are not the mode's: {picture:.1?} vs {expected:.1?}"
    );
    picture
}

fn in_vm_checks() {
    clients::load_module(VIEW_NR, DATA_NR);
    let sdid = Sdid::start(VIEW_NR, DATA_NR, TI, 15);

    // The view node, in two modes that render differently.
    let mut means = Vec::new();
    for mode in ["raw", "separation"] {
        sdid.set_mode(mode);
        let expected = sdid.snapshot_mean_rgb();
        let frame = read_view(&sdid);
        means.push(check_view(&frame, expected, mode));
    }
    let change: f64 = means[0]
        .iter()
        .zip(means[1])
        .map(|(a, b)| (a - b).abs())
        .sum();
    assert!(
        change > 6.0,
        "set-mode did not change what v4l2src reads: {means:.1?}"
    );

    // The data node: Y16 at the sensor size, DN + 32768; in two-shot sdid
    // publishes at half the node's frame interval, where the module's
    // sustain_framerate would repeat every frame.
    check_data(&sdid, "raw");
    check_data(&sdid, "two-shot");
}

/// Reads FRAMES data frames (GRAY16_LE at the sensor size) in `mode`, as
/// docs/loopback.md tells users to: the sink must not keep the buffer it
/// rendered last (`enable-last-sample=false`), or v4l2loopback can hand
/// that buffer to v4l2src again while it is held ("buffer N was not
/// queued"). Checks that no frame came twice (sdid keeps the module's
/// sustain_framerate repeat off; the simulator's noise makes every frame
/// differ) and the last one's mean against the mode's `.npy` snapshot.
fn check_data(sdid: &Sdid, mode: &str) {
    sdid.set_mode(mode);
    let expected_dn = sdid.snapshot_mean_dn();
    let file = "/tmp/sdi-clients/data.y16";
    let (log, secs) = gst(&format!(
        "v4l2src device={} num-buffers={FRAMES} ! video/x-raw,format=GRAY16_LE,width={},height={} \
         ! filesink enable-last-sample=false location={file}",
        sdid.data.display(),
        TI.width,
        TI.height
    ));
    let caps = format!(
        "v4l2src0.GstPad:src: caps = video/x-raw, format=(string)GRAY16_LE, width=(int){}, height=(int){}",
        TI.width, TI.height
    );
    assert!(
        log.contains(&caps),
        "v4l2src did not negotiate {caps}:\n{log}"
    );
    let bytes = std::fs::read(file).expect("read data frames");
    let size = TI.width * TI.height * 2;
    assert_eq!(bytes.len(), FRAMES * size, "data: {FRAMES} frames of Y16");
    let frames: Vec<&[u8]> = bytes.chunks_exact(size).collect();
    let repeats: Vec<usize> = (1..FRAMES)
        .filter(|&i| frames[i] == frames[i - 1])
        .collect();
    assert!(
        repeats.is_empty(),
        "{mode}: frames {repeats:?} repeat the one before (the module's sustain_framerate repeat is on)"
    );
    let last = &bytes[(FRAMES - 1) * size..];
    let n = last.len() / 2;
    let dn = last
        .chunks_exact(2)
        .map(|c| f64::from(u16::from_le_bytes([c[0], c[1]])) - 32768.0)
        .sum::<f64>()
        / n as f64;
    eprintln!(
        "gst data, {mode}: {FRAMES} frames in {secs:.1} s; mean DN {dn:.1}, snapshot {expected_dn:.1}"
    );
    assert!(
        (dn - expected_dn).abs() < 5.0 + 0.05 * expected_dn.abs(),
        "{mode}: data node mean DN {dn:.1} is not the frame's {expected_dn:.1}"
    );
}

#[test]
fn vm_gstreamer_reads_both_nodes() {
    if crate::GUEST.on_host() {
        return;
    }
    in_vm_checks();
}
