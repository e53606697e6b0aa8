//! CPU per frame of the PipeWire sink against the y4m sink, side by side in
//! one run, at a 640x480 sensor size; where a v4l2loopback node labelled
//! `sdi-bench` exists (the VM: `tests/vm/bench-sinks.sh`), the loopback
//! sink too, read by `gst-launch-1.0 v4l2src`.
//!
//! Each sink gets the same synthetic frames, paced at `--rate` Hz, with one
//! reader attached in another process (`gst-launch-1.0 pipewiresrc !
//! fakesink`, `cat FIFO > /dev/null`). The figure is this process's CPU time
//! (the writing thread; for PipeWire plus the camera process it feeds,
//! `sdi-pipewire-camera`, a child of this one) divided by the frames the sink
//! published. The readers' CPU (reaped children) is printed
//! beside it. Each write gets a fresh [`OutFrame`] (its pictures are
//! rendered once per frame and kept): one copy of the 640x480 output per
//! frame, the same for every sink, is counted with it.
//!
//! `cargo run --release -p sdi-tests --bin sink_bench -- [FRAMES] [RATE_HZ]`

use std::fs::File;
use std::os::unix::fs::OpenOptionsExt;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use nix::sys::resource::{getrusage, UsageWho};
use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
use sdi_core::mode::{ModeId, ModeOutput};
use sdi_core::view::{PixelFormat, ViewRenderer};
use sdi_daemon::out_frame::OutFrame;
use sdi_daemon::sink::loopback::LoopbackSink;
use sdi_daemon::sink::pipewire::{PipewireSink, VIEW_NODE};
use sdi_daemon::sink::y4m::Y4mSink;
use sdi_daemon::sink::Sink;
use sdi_tests::pipewire::{missing_tools, Session};
use sdi_tests::process::Reaped;
use sdi_tests::wait::wait_for;

const WIDTH: usize = 640;
const HEIGHT: usize = 480;

fn cpu_s(who: UsageWho) -> f64 {
    getrusage(who).map_or(0.0, |u| {
        let t = |tv: nix::sys::time::TimeVal| tv.tv_sec() as f64 + tv.tv_usec() as f64 * 1e-6;
        t(u.user_time()) + t(u.system_time())
    })
}

/// User + system CPU seconds of process `pid` so far (/proc/PID/stat).
fn process_cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command name (which may hold spaces): utime and stime
    // are the 12th and 13th, in clock ticks.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let ticks: Vec<f64> = rest
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|t| t.parse().ok())
        .collect();
    let hz = nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK)
        .ok()
        .flatten()
        .unwrap_or(100) as f64;
    ticks.iter().sum::<f64>() / hz
}

/// Frame `k`: a moving ramp of signed DN.
fn fill(out: &mut ModeOutput, k: usize) {
    for (i, v) in out.signed_dn.data.iter_mut().enumerate() {
        let (x, y) = (i % WIDTH, i / WIDTH);
        *v = ((x + 3 * y + 5 * k) % 2001) as f32 - 1000.0;
    }
    out.sequence = k as u64;
    out.timestamp_us = k as u64 * 16_667;
}

struct Run {
    name: String,
    wall_s: f64,
    cpu_s: f64,
    written: usize,
    published: u64,
    reader_cpu_s: f64,
}

impl Run {
    fn print(&self) {
        let per = |n: f64| {
            if n > 0.0 {
                self.cpu_s * 1e3 / n
            } else {
                f64::NAN
            }
        };
        println!(
            "{:<42} {:>5} written {:>6} published  {:>7.3} ms CPU/published frame  ({:>5.1} % of a core)  reader {:>7.3} ms/frame",
            self.name,
            self.written,
            self.published,
            per(self.published as f64),
            self.cpu_s / self.wall_s * 100.0,
            if self.published > 0 {
                self.reader_cpu_s * 1e3 / self.published as f64
            } else {
                f64::NAN
            },
        );
    }
}

/// No sink: the view rendering every sink starts with (RGB8 at the sensor
/// size, as the y4m sink renders it), for reference.
struct RenderOnly {
    view: ViewRenderer,
}

impl Sink for RenderOnly {
    fn info(&self) -> sdi_daemon::sink::SinkInfo {
        sdi_daemon::sink::SinkInfo {
            kind: sdi_daemon::sink::SinkKindName::Y4m,
            device: String::new(),
            format: "RGB3".into(),
            width: WIDTH as u32,
            height: HEIGHT as u32,
        }
    }

    fn write(&mut self, frame: &OutFrame) -> Result<(), sdi_daemon::sink::SinkError> {
        frame.view(&mut self.view)?;
        Ok(())
    }

    fn write_no_signal(&mut self, _timestamp_us: u64) -> Result<(), sdi_daemon::sink::SinkError> {
        Ok(())
    }
}

fn bench_render(frames: usize, rate_hz: f64) -> Run {
    let mut sink = RenderOnly {
        view: ViewRenderer::new(WIDTH, HEIGHT, PixelFormat::Rgb24),
    };
    let (wall_s, cpu) = drive(&mut sink, frames, rate_hz);
    Run {
        name: "render only (colormap)".into(),
        wall_s,
        cpu_s: cpu,
        written: frames,
        published: frames as u64,
        reader_cpu_s: 0.0,
    }
}

/// Writes `frames` frames at `rate_hz` into `sink`; CPU of this process.
fn drive(sink: &mut dyn Sink, frames: usize, rate_hz: f64) -> (f64, f64) {
    let display = DisplayMap {
        colormap: Colormap::Diverging,
        range: DisplayRange::SymmetricAuto,
    };
    // Made beforehand so only the sink's work is timed.
    let outputs: Vec<ModeOutput> = (0..16)
        .map(|k| {
            let mut out = ModeOutput::new(WIDTH, HEIGHT);
            fill(&mut out, k);
            out
        })
        .collect();
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let (c0, t0) = (cpu_s(UsageWho::RUSAGE_SELF), Instant::now());
    for k in 0..frames {
        let frame = OutFrame::new(
            outputs[k % outputs.len()].clone(),
            ModeId::DepthEdge,
            display,
        );
        if let Err(e) = sink.write(&frame) {
            eprintln!("sink_bench: write: {e}");
        }
        let next = t0 + period * (k as u32 + 1);
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
    }
    // Let the PipeWire thread finish the last frame.
    std::thread::sleep(period);
    (
        t0.elapsed().as_secs_f64(),
        cpu_s(UsageWho::RUSAGE_SELF) - c0,
    )
}

fn bench_pipewire(s: &Session, caps: &str, frames: usize, rate_hz: f64) -> Run {
    // The camera program built beside this one (`cargo build -p sdi-pipewire-camera`).
    let program = sdi_daemon::sink::pipewire_launch::find_program().unwrap_or_else(|e| {
        eprintln!("sink_bench: {e}");
        std::process::exit(2)
    });
    let spec = PipewireSink::spec(WIDTH, HEIGHT, rate_hz, sdi_core::mode::ModeId::Raw, None);
    let mut sink =
        PipewireSink::open(&program, spec).unwrap_or_else(|e| panic!("PipeWire sink: {e}"));
    let camera = sink.camera_pid().expect("the camera process's pid");
    let reader = (!caps.is_empty()).then(|| s.reader(VIEW_NODE, caps));
    if reader.is_some() {
        wait_for(
            "a reader on the PipeWire node",
            // gst-launch under TCG (the VM) takes tens of seconds to start.
            Duration::from_secs(180),
            || sink.view_streaming().then_some(()),
        );
    }
    let before = sink.published().0;
    let camera_cpu0 = process_cpu_s(camera);
    let (wall_s, cpu) = drive(&mut sink, frames, rate_hz);
    // The camera reports its count at most every 200 ms.
    std::thread::sleep(Duration::from_millis(400));
    let published = sink.published().0 - before;
    // The camera process's share: PipeWire's loop and the copy it receives.
    let cpu = cpu + process_cpu_s(camera) - camera_cpu0;
    sink.stop_camera();
    drop(sink);
    wait_for("the camera process to end", Duration::from_secs(30), || {
        (!std::path::Path::new(&format!("/proc/{camera}")).exists()).then_some(())
    });
    let c0 = cpu_s(UsageWho::RUSAGE_CHILDREN);
    drop(reader);
    Run {
        name: if caps.is_empty() {
            "pipewire, no reader".into()
        } else {
            format!("pipewire, reader {caps}")
        },
        wall_s,
        cpu_s: cpu,
        written: frames,
        published,
        reader_cpu_s: cpu_s(UsageWho::RUSAGE_CHILDREN) - c0,
    }
}

fn bench_y4m(s: &Session, frames: usize, rate_hz: f64) -> Run {
    let fifo = s.dir.path().join("bench.y4m");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::from_bits_truncate(0o600)).expect("mkfifo");
    // The reader's end opened here first, so the sink finds a reader from
    // its first frame; then handed to `cat` as blocking stdin.
    let read_end = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(&fifo)
        .expect("open FIFO");
    {
        use nix::fcntl::{fcntl, FcntlArg, OFlag};
        use std::os::fd::AsRawFd;
        fcntl(read_end.as_raw_fd(), FcntlArg::F_SETFL(OFlag::empty())).expect("blocking FIFO");
    }
    let mut sink = Y4mSink::new(Some(&fifo), WIDTH, HEIGHT, rate_hz).expect("y4m sink");
    let reader = Reaped(
        Command::new("cat")
            .stdin(Stdio::from(read_end))
            .stdout(File::create("/dev/null").expect("/dev/null"))
            .spawn()
            .expect("start cat"),
    );
    let (wall_s, cpu) = drive(&mut sink, frames, rate_hz);
    drop(sink);
    let c0 = cpu_s(UsageWho::RUSAGE_CHILDREN);
    let mut reader = reader;
    let _ = reader.0.wait();
    Run {
        name: "y4m (C444 FIFO), reader cat".into(),
        wall_s,
        cpu_s: cpu,
        written: frames,
        published: frames as u64,
        reader_cpu_s: cpu_s(UsageWho::RUSAGE_CHILDREN) - c0,
    }
}

/// The card label of the loopback node the bench writes to.
const LOOPBACK_LABEL: &str = "sdi-bench";

/// The loopback sink (YUYV 640x480 view node), read by GStreamer's v4l2src,
/// if a node labelled [`LOOPBACK_LABEL`] exists.
fn bench_loopback(frames: usize, rate_hz: f64) -> Option<Run> {
    let dev = v4l2loopback_glue::find_device(LOOPBACK_LABEL).ok()?;
    let mut sink = LoopbackSink::open(LOOPBACK_LABEL, "", WIDTH, HEIGHT, rate_hz)
        .unwrap_or_else(|e| panic!("loopback sink: {e}"));
    // The writer streams from open (the node is a capture device only
    // then, with exclusive_caps=1); one frame before the reader opens.
    let display = DisplayMap {
        colormap: Colormap::Diverging,
        range: DisplayRange::SymmetricAuto,
    };
    let mut first = ModeOutput::new(WIDTH, HEIGHT);
    fill(&mut first, 0);
    let _ = sink.write(&OutFrame::new(first, ModeId::DepthEdge, display));
    let reader = Reaped(
        Command::new("gst-launch-1.0")
            .arg("-q")
            .args(format!("v4l2src device={} ! fakesink", dev.path.display()).split(' '))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start gst-launch-1.0"),
    );
    std::thread::sleep(Duration::from_secs(3));
    let (wall_s, cpu) = drive(&mut sink, frames, rate_hz);
    drop(sink);
    let c0 = cpu_s(UsageWho::RUSAGE_CHILDREN);
    drop(reader);
    Some(Run {
        name: "loopback (YUYV view node), reader v4l2src".into(),
        wall_s,
        cpu_s: cpu,
        written: frames,
        published: frames as u64,
        reader_cpu_s: cpu_s(UsageWho::RUSAGE_CHILDREN) - c0,
    })
}

fn main() {
    let mut args = std::env::args().skip(1);
    let frames: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(300);
    let rate_hz: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(60.0);
    if let Some(why) = missing_tools() {
        eprintln!("sink_bench: {why}");
        std::process::exit(2);
    }
    let s = Session::start();
    // This process is the PipeWire client: point it at the private daemon
    // (before any thread of ours starts).
    std::env::set_var("XDG_RUNTIME_DIR", s.runtime_dir());
    std::env::remove_var("PIPEWIRE_REMOTE");
    println!(
        "sink_bench: {frames} frames of {WIDTH}x{HEIGHT} at {rate_hz} Hz per sink (view 640x480)"
    );
    // Printed as each run ends.
    if let Some(r) = bench_loopback(frames, rate_hz) {
        r.print();
    }
    bench_y4m(&s, frames, rate_hz).print();
    bench_pipewire(&s, "video/x-raw,format=YUY2", frames, rate_hz).print();
    bench_pipewire(&s, "video/x-raw,format=RGB", frames, rate_hz).print();
    bench_pipewire(&s, "", frames, rate_hz).print();
    bench_render(frames, rate_hz).print();
}
