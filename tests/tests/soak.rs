//! Soak: one sdid on the simulator on a private bus while clients come and
//! go: mode switches, snapshots and short recordings (through `sdictl`, so
//! over descriptors), y4m FIFO readers opening and closing, and 10,000-call
//! floods from one connection. Every few seconds the test samples sdid's
//! resident memory (`VmRSS`), its open descriptors (`/proc/PID/fd`) and the
//! frame rate it reports (`Stats`); it prints that curve and asserts:
//!
//! - RSS and descriptors flat: after the warm-up (which includes the first
//!   two floods, the high-water mark of queued calls: the second flood can
//!   still add ~9 MB of allocator arenas and buffer capacity) the median RSS
//!   of the last third of the samples is at most [`RSS_TREND_KIB`] above
//!   that of the first third (a leak's trend), and no sample exceeds the
//!   warm-up's peak by more than [`RSS_GROWTH_KIB`] resp. [`FD_GROWTH`];
//! - the frame rate held: the median sample at least
//!   [`MEDIAN_FPS_FRACTION`] of the configured rate, none below
//!   [`MIN_FPS_FRACTION`], and frames keep coming;
//! - a fair share: during each flood, the calls of another client
//!   (`SetMode`, which waits for a frame, and uncached property reads) take
//!   at most 200 ms longer at the 99th percentile than the same calls
//!   without a flood in the same run, each within 600 ms (or 200 ms over
//!   the slowest call without a flood: on a loaded 2-core machine those
//!   alone reach 190-530 ms); where the machine is slow enough to stretch
//!   the flood itself, at most 1/40 resp. 1/20 of the flood's length (a
//!   call served behind it would wait for most of it); and every flood
//!   call is answered;
//! - every client call of the workload succeeded, and sdid is still alive.
//!
//! About 2 minutes by default; `SDI_SOAK_SECS=3600` soaks for an hour.

use std::fs;
use std::io::{ErrorKind, Read};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::process::{Output, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::require_dbus;
use zbus::proxy::CacheProperties;

/// Soak length unless `SDI_SOAK_SECS` asks for another.
const DEFAULT_SECS: u64 = 120;
const FPS: f64 = 30.0;
const FLOOD_CALLS: usize = 10_000;
/// What a flood may add to another client's calls (docs/dbus.md, "Fair
/// share"), at the 99th percentile; every call within 3x, the margin of
/// `dbus_fair_share.rs` for a loaded 2-core machine (on one, the same calls
/// without any flood took up to 190-530 ms).
const LATENCY_BOUND: Duration = Duration::from_millis(200);
const LATENCY_MAX_LOADED: Duration = Duration::from_millis(600);
const SAMPLE_EVERY: Duration = Duration::from_secs(2);
/// Quiet time between the end of one flood and the start of the next.
const FLOOD_GAP: Duration = Duration::from_secs(30);
/// Settling time after the second flood (the first when only one fits)
/// before the flat part starts.
const SETTLE: Duration = Duration::from_secs(10);
/// Allowed growth of any sample over the warm-up peak. An hour's soak
/// (10 s samples) reached its plateau only after about 8 floods (~500 s):
/// 83-96 MB with its median flat (87.0 MB in the first third, 87.8 MB in the
/// last), each sample up to ~5 MB over the plateau depending on where a
/// flood's queued calls stood; 8 MB over a 2-flood warm-up peak of 82.9 MB
/// failed it at 1022 s (91.7 MB) without any growth.
const RSS_GROWTH_KIB: u64 = 16 * 1024;
/// Allowed growth of the median RSS from the first to the last third of the
/// flat part: what a leak shows, whatever the soak's length.
const RSS_TREND_KIB: u64 = 4 * 1024;
const FD_GROWTH: usize = 4;
/// Frame rate held: the median Stats sample at least 90 % of the configured
/// rate, none below half (a 500 ms window on a loaded machine).
const MEDIAN_FPS_FRACTION: f64 = 0.9;
const MIN_FPS_FRACTION: f64 = 0.5;
/// Modes the switcher walks through (all but the separation estimator,
/// whose per-frame cost is not what this test is about).
const MODES: [&str; 5] = ["raw", "depth-edge", "bipolar-colour", "two-shot", "raw"];

/// `SDI_SOAK_SECS`, at least 60 (time for one flood and a flat part).
fn soak_secs() -> u64 {
    std::env::var("SDI_SOAK_SECS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(DEFAULT_SECS)
        .max(60)
}

/// Starts sdid (simulator, y4m into `dir/view.y4m`, state in `dir/state`,
/// stderr to `dir/sdid.log`) and waits until it answers.
fn start_sdid(bus: &Bus, dir: &Path) -> Daemon {
    let state = dir.join("state");
    fs::create_dir_all(&state).unwrap();
    let log = fs::File::create(dir.join("sdid.log")).unwrap();
    let mut cmd = Daemon::bare_command(bus, &[]);
    cmd.args(["--backend", "sim", "--sink", "y4m", "--y4m-path"])
        .arg(dir.join("view.y4m"))
        .args(["--frame-rate-hz", &FPS.to_string(), "--exposure-us", "2000"])
        .arg("--state-dir")
        .arg(&state)
        .stdout(Stdio::null())
        .stderr(log);
    let d = Daemon::spawn(bus, &mut cmd);
    d.wait_ready();
    d
}

/// What the workload did, and what went wrong.
#[derive(Default)]
struct Tally {
    mode_switches: AtomicU64,
    snapshots: AtomicU64,
    recordings: AtomicU64,
    reader_sessions: AtomicU64,
    reader_bytes: AtomicU64,
    errors: Mutex<Vec<String>>,
}

impl Tally {
    fn fail(&self, what: String) {
        eprintln!("soak error: {what}");
        self.errors.lock().unwrap().push(what);
    }

    /// Counts `out` as a success of `counter`, or records why not.
    fn check(&self, counter: &AtomicU64, what: &str, out: &Output) -> bool {
        if out.status.success() {
            counter.fetch_add(1, Ordering::Relaxed);
            true
        } else {
            self.fail(format!(
                "{what}: {} {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            ));
            false
        }
    }
}

/// Runs `step` (given its iteration number) until `stop`.
fn worker(
    stop: &Arc<AtomicBool>,
    mut step: impl FnMut(u64) + Send + 'static,
) -> std::thread::JoinHandle<()> {
    let stop = stop.clone();
    std::thread::spawn(move || {
        let mut i = 0;
        while !stop.load(Ordering::Relaxed) {
            step(i);
            i += 1;
        }
    })
}

/// One y4m reader session: opens the FIFO, checks the header, reads for
/// `read_for`, closes. Never blocks longer than a poll timeout, so the soak
/// ends even if sdid stops writing.
fn read_fifo(fifo: &Path, read_for: Duration, tally: &Tally) {
    let mut f = match fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(fifo)
    {
        Ok(f) => f,
        Err(e) => return tally.fail(format!("open {}: {e}", fifo.display())),
    };
    let mut head = Vec::new();
    let mut bytes = 0u64;
    let mut buf = vec![0u8; 1 << 16];
    let t0 = Instant::now();
    while t0.elapsed() < read_for {
        let mut fds = [PollFd::new(f.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(500u16)) {
            Ok(0) => continue,
            Ok(_) => {}
            Err(e) => return tally.fail(format!("poll the FIFO: {e}")),
        }
        match f.read(&mut buf) {
            // No writer (yet, or sdid closed its end): wait for it.
            Ok(0) => std::thread::sleep(Duration::from_millis(10)),
            Ok(n) => {
                if head.len() < 9 {
                    head.extend_from_slice(&buf[..n.min(9 - head.len())]);
                }
                bytes += n as u64;
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {}
            Err(e) => return tally.fail(format!("read the FIFO: {e}")),
        }
    }
    if head != b"YUV4MPEG2" {
        tally.fail(format!(
            "y4m reader {} got {bytes} bytes starting {:?}, not the YUV4MPEG2 header",
            tally.reader_sessions.load(Ordering::Relaxed),
            String::from_utf8_lossy(&head)
        ));
        return;
    }
    tally.reader_sessions.fetch_add(1, Ordering::Relaxed);
    tally.reader_bytes.fetch_add(bytes, Ordering::Relaxed);
}

/// One sample of sdid.
#[derive(Debug, Clone)]
struct Sample {
    t_s: f64,
    rss_kib: u64,
    fds: usize,
    fps: f64,
    frames: u64,
    flooding: bool,
}

fn rss_kib(pid: u32) -> u64 {
    fs::read_to_string(format!("/proc/{pid}/status"))
        .expect("sdid's /proc status")
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("VmRSS")
}

fn open_fds(pid: u32) -> usize {
    fs::read_dir(format!("/proc/{pid}/fd"))
        .expect("sdid's /proc fd")
        .count()
}

/// Another client's calls, timed: a `SetMode` (answered by the next frame)
/// and an uncached property read.
async fn probe_once(probe: &sdi_api::Camera1Proxy<'_>, k: usize) -> [Duration; 2] {
    let t = Instant::now();
    probe
        .set_mode(if k.is_multiple_of(4) {
            "raw"
        } else {
            "depth-edge"
        })
        .await
        .expect("the other client's SetMode");
    let set_mode = t.elapsed();
    let t = Instant::now();
    probe
        .exposure_us()
        .await
        .expect("the other client's ExposureUs");
    [set_mode, t.elapsed()]
}

/// [`probe_once`] every 100 ms until `until` (from `t0`): the same calls
/// without a flood, for comparison.
async fn probe_until(
    probe: &sdi_api::Camera1Proxy<'_>,
    t0: Instant,
    until: Duration,
) -> Vec<Duration> {
    let mut latencies = Vec::new();
    while t0.elapsed() < until {
        latencies.extend(probe_once(probe, latencies.len()).await);
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    latencies
}

/// (99th percentile, maximum) of `latencies` (not empty).
fn p99_and_max(latencies: &[Duration]) -> (Duration, Duration) {
    let mut sorted = latencies.to_vec();
    sorted.sort();
    (
        sorted[(sorted.len() - 1) * 99 / 100],
        sorted[sorted.len() - 1],
    )
}

/// "max X ms, 99th percentile Y ms, mean Z ms" of `latencies`.
fn summary(latencies: &[Duration]) -> String {
    let mut ms: Vec<f64> = latencies.iter().map(|d| d.as_secs_f64() * 1e3).collect();
    ms.sort_by(f64::total_cmp);
    let at = |q: f64| {
        ms.get(((ms.len() as f64 - 1.0) * q).round() as usize)
            .copied()
    };
    format!(
        "{} calls, max {:.0} ms, 99th percentile {:.0} ms, median {:.0} ms",
        ms.len(),
        at(1.0).unwrap_or(0.0),
        at(0.99).unwrap_or(0.0),
        at(0.5).unwrap_or(0.0)
    )
}

/// One flood: `FLOOD_CALLS` SetMode calls sent on `flooder` without
/// waiting, while `probe` (another connection) times its own calls.
/// Returns the probe latencies and how long the flood took to be answered.
async fn flood(
    flooder: &zbus::Connection,
    probe: &sdi_api::Camera1Proxy<'_>,
) -> (Vec<Duration>, Duration) {
    let mut replies = zbus::MessageStream::from(flooder);
    let answered = Arc::new(AtomicU64::new(0));
    let drained = {
        let answered = answered.clone();
        tokio::spawn(async move {
            while let Some(m) = replies.next().await {
                if m.is_ok_and(|m| {
                    matches!(
                        m.message_type(),
                        zbus::message::Type::MethodReturn | zbus::message::Type::Error
                    )
                }) && answered.fetch_add(1, Ordering::Relaxed) + 1 == FLOOD_CALLS as u64
                {
                    break;
                }
            }
        })
    };
    let t0 = Instant::now();
    sdi_tests::dbus::send_set_mode_flood(flooder, FLOOD_CALLS).await;
    let mut latencies = Vec::new();
    while answered.load(Ordering::Relaxed) < FLOOD_CALLS as u64 {
        assert!(
            t0.elapsed() < Duration::from_secs(600),
            "the flood was not answered in 600 s ({} of {FLOOD_CALLS})",
            answered.load(Ordering::Relaxed)
        );
        latencies.extend(probe_once(probe, latencies.len()).await);
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    drained.await.unwrap();
    (latencies, t0.elapsed())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn soak_clients_come_and_go_memory_and_descriptors_stay_flat() {
    require_dbus!();
    let secs = soak_secs();
    let total = Duration::from_secs(secs);
    let dir = tempfile::tempdir().unwrap();
    let bus = Bus::start();
    let sdid = Arc::new(start_sdid(&bus, dir.path()));
    let pid = sdid.pid();
    let t0 = Instant::now();
    let stop = Arc::new(AtomicBool::new(false));
    let tally = Arc::new(Tally::default());

    // The workload, each client a process of its own (connections come and go).
    let out = dir.path().join("out");
    fs::create_dir_all(&out).unwrap();
    let mut workers = Vec::new();
    workers.push({
        let (sdid, tally) = (sdid.clone(), tally.clone());
        worker(&stop, move |i| {
            let mode = MODES[i as usize % MODES.len()];
            let o = sdid.ctl(&["set-mode", mode]);
            tally.check(&tally.mode_switches, &format!("set-mode {mode}"), &o);
            std::thread::sleep(Duration::from_millis(700));
        })
    });
    workers.push({
        let (sdid, tally, out) = (sdid.clone(), tally.clone(), out.clone());
        worker(&stop, move |i| {
            let file = out.join(format!("snap-{i}.{}", ["png", "npy"][i as usize % 2]));
            let o = sdid.ctl(&["snapshot", file.to_str().unwrap()]);
            if tally.check(&tally.snapshots, "snapshot", &o)
                && !fs::metadata(&file).is_ok_and(|m| m.len() > 0)
            {
                tally.fail(format!("snapshot {} is empty", file.display()));
            }
            let _ = fs::remove_file(&file);
            std::thread::sleep(Duration::from_millis(300));
        })
    });
    workers.push({
        let (sdid, tally, out) = (sdid.clone(), tally.clone(), out.clone());
        worker(&stop, move |i| {
            let file = out.join(format!("rec-{i}.sdirec"));
            let o = sdid.ctl(&["record", file.to_str().unwrap(), "--seconds", "1"]);
            if tally.check(&tally.recordings, "record", &o)
                && !fs::metadata(&file).is_ok_and(|m| m.len() > 0)
            {
                tally.fail(format!("recording {} is empty", file.display()));
            }
            let _ = fs::remove_file(&file);
            std::thread::sleep(Duration::from_millis(500));
        })
    });
    workers.push({
        let (tally, fifo) = (tally.clone(), dir.path().join("view.y4m"));
        worker(&stop, move |i| {
            // Sessions of 0.3 to 1.5 s; the pause after one stays above a
            // few frame periods (a reader that reopens within one frame
            // period is a separate finding of the issue).
            read_fifo(&fifo, Duration::from_millis(300 + (i * 300) % 1200), &tally);
            std::thread::sleep(Duration::from_millis(250));
        })
    });

    // The sampler.
    let samples: Arc<Mutex<Vec<Sample>>> = Arc::default();
    let flooding = Arc::new(AtomicBool::new(false));
    let sampler = {
        let conn = bus.connect().await;
        let (stop, samples, flooding) = (stop.clone(), samples.clone(), flooding.clone());
        tokio::spawn(async move {
            let cam = sdi_api::Camera1Proxy::builder(&conn)
                .cache_properties(CacheProperties::No)
                .build()
                .await
                .unwrap();
            while !stop.load(Ordering::Relaxed) {
                let stats = cam.stats().await.expect("Stats");
                let s = Sample {
                    t_s: t0.elapsed().as_secs_f64(),
                    rss_kib: rss_kib(pid),
                    fds: open_fds(pid),
                    fps: stats.fps,
                    frames: stats.frames,
                    flooding: flooding.load(Ordering::Relaxed),
                };
                samples.lock().unwrap().push(s);
                tokio::time::sleep(SAMPLE_EVERY).await;
            }
        })
    };

    // Floods, from one connection, while another client probes.
    let flooder = bus.connect().await;
    let probe_conn = bus.connect().await;
    let probe = sdi_api::Camera1Proxy::builder(&probe_conn)
        .cache_properties(CacheProperties::No)
        .build()
        .await
        .unwrap();
    let mut floods: Vec<(f64, Duration, Vec<Duration>)> = Vec::new();
    let mut quiet = probe_until(&probe, t0, Duration::from_secs(5)).await;
    let mut warm_up_end = None;
    // A flood starts only when it (about 40 s) and a flat part after it fit.
    while t0.elapsed() + Duration::from_secs(40) < total {
        let start = t0.elapsed().as_secs_f64();
        flooding.store(true, Ordering::Relaxed);
        let (latencies, took) = flood(&flooder, &probe).await;
        flooding.store(false, Ordering::Relaxed);
        floods.push((start, took, latencies));
        if floods.len() <= 2 {
            warm_up_end = Some(t0.elapsed() + SETTLE);
        }
        let gap_end = (t0.elapsed() + FLOOD_GAP).min(total);
        quiet.extend(probe_until(&probe, t0, gap_end).await);
    }
    quiet.extend(probe_until(&probe, t0, total).await);
    stop.store(true, Ordering::Relaxed);
    sampler.await.unwrap();
    for w in workers {
        w.join().unwrap();
    }
    let soaked = t0.elapsed();

    // The curve.
    let samples = samples.lock().unwrap().clone();
    eprintln!("soak: {:.0} s; sdid pid {pid}", soaked.as_secs_f64());
    eprintln!("   t_s  rss_kib  fds    fps    frames  flood");
    for s in &samples {
        eprintln!(
            "{:6.1} {:8} {:4} {:6.1} {:9}  {}",
            s.t_s,
            s.rss_kib,
            s.fds,
            s.fps,
            s.frames,
            if s.flooding { "yes" } else { "" }
        );
    }
    for (start, took, lat) in &floods {
        eprintln!(
            "flood at {start:.0} s: {FLOOD_CALLS} SetMode answered in {:.1} s; another \
             client's calls meanwhile: {}",
            took.as_secs_f64(),
            summary(lat)
        );
    }
    eprintln!("the same calls without a flood: {}", summary(&quiet));
    let t = &tally;
    eprintln!(
        "workload: {} mode switches, {} snapshots, {} recordings, {} y4m reader sessions ({} MB)",
        t.mode_switches.load(Ordering::Relaxed),
        t.snapshots.load(Ordering::Relaxed),
        t.recordings.load(Ordering::Relaxed),
        t.reader_sessions.load(Ordering::Relaxed),
        t.reader_bytes.load(Ordering::Relaxed) / 1_000_000
    );
    let log = fs::read_to_string(dir.path().join("sdid.log")).unwrap_or_default();
    let lines: Vec<&str> = log.lines().collect();
    eprintln!(
        "sdid log: {} lines; last:\n{}",
        lines.len(),
        lines[lines.len().saturating_sub(3)..].join("\n")
    );

    // Alive, and every client call succeeded.
    let mut sdid = Arc::into_inner(sdid).expect("the workers are done");
    let alive = sdid.child.try_wait().unwrap().is_none();
    assert!(alive, "sdid died");
    assert!(!log.contains("panicked"), "sdid panicked:\n{log}");
    let errors = tally.errors.lock().unwrap();
    assert!(
        errors.is_empty(),
        "{} client errors: {errors:#?}",
        errors.len()
    );
    for counter in [
        &t.mode_switches,
        &t.snapshots,
        &t.recordings,
        &t.reader_sessions,
    ] {
        assert!(counter.load(Ordering::Relaxed) > 0, "a worker never ran");
    }

    // Fair share: the flood adds at most 200 ms to another client's 99th
    // percentile, measured against the same calls without a flood in this
    // run, and every call stays within the loaded-machine margin. Against
    // the quiet calls, not an absolute figure: at load 9 on 2 cores the
    // calls without any flood reached 165 ms (99th percentile) and 527 ms.
    // What the test guards against is a call served behind the flood,
    // which waits for most of it (28-35 s, paced by sdid's fair share
    // rather than by the machine). On CI's machine with both guests busy
    // (sdid's own frame rate at 12-20 fps between floods too) the calls
    // took p99 502 ms and max 631 ms during a flood, so the bounds are at
    // least 1/40 (p99) and 1/20 (max) of the flood's length: 20 times
    // shorter than a wait behind it. How fast calls are is the benches'.
    assert!(!floods.is_empty(), "no flood ran");
    let (quiet_p99, quiet_max) = p99_and_max(&quiet);
    for (start, took, lat) in &floods {
        let (p99, max) = p99_and_max(lat);
        let p99_bound = (quiet_p99 + LATENCY_BOUND).max(*took / 40);
        let max_bound = LATENCY_MAX_LOADED
            .max(quiet_max + LATENCY_BOUND)
            .max(*took / 20);
        assert!(
            p99 <= p99_bound && max <= max_bound,
            "under the flood at {start:.0} s ({took:.1?}) another client's calls: 99th \
             percentile {p99:?} (bound {p99_bound:?}: {LATENCY_BOUND:?} over {quiet_p99:?} \
             without a flood, or 1/40 of the flood), max {max:?} (bound {max_bound:?})"
        );
    }

    // Flat, after the warm-up.
    let warm_up_end = warm_up_end.expect("a flood ran").as_secs_f64();
    let (warm, flat): (Vec<&Sample>, Vec<&Sample>) =
        samples.iter().partition(|s| s.t_s < warm_up_end);
    assert!(flat.len() >= 3, "too few samples after the warm-up");
    let rss_peak = warm.iter().map(|s| s.rss_kib).max().unwrap_or(0);
    let fds_peak = warm.iter().map(|s| s.fds).max().unwrap_or(0);
    // A leak is a trend: the median of the flat part's last third against
    // its first third. The ceiling over the warm-up peak bounds the rest.
    let third = flat.len() / 3;
    let median_rss = |part: &[&Sample]| {
        let mut v: Vec<u64> = part.iter().map(|s| s.rss_kib).collect();
        v.sort_unstable();
        v.get(v.len() / 2).copied().unwrap_or(0)
    };
    let (early, late) = (
        median_rss(&flat[..third]),
        median_rss(&flat[flat.len() - third..]),
    );
    eprintln!("RSS median, first third of the flat part {early} KiB, last third {late} KiB");
    assert!(
        late <= early + RSS_TREND_KIB,
        "RSS grows: median {early} KiB in the first third of the flat part, {late} KiB in the last"
    );
    for s in &flat {
        assert!(
            s.rss_kib <= rss_peak + RSS_GROWTH_KIB,
            "RSS grew to {} KiB at {:.0} s (warm-up peak {rss_peak} KiB)",
            s.rss_kib,
            s.t_s
        );
        assert!(
            s.fds <= fds_peak + FD_GROWTH,
            "{} descriptors at {:.0} s (warm-up peak {fds_peak})",
            s.fds,
            s.t_s
        );
    }
    // Frame rate held, the first sample (start-up window) aside: the
    // median near the configured rate, no window far below it.
    let mut fps: Vec<f64> = samples.iter().skip(1).map(|s| s.fps).collect();
    fps.sort_by(f64::total_cmp);
    let (min, median) = (fps[0], fps[fps.len() / 2]);
    eprintln!("Stats fps: median {median:.1}, min {min:.1} (configured {FPS})");
    assert!(
        median >= MEDIAN_FPS_FRACTION * FPS,
        "median {median:.1} fps (configured {FPS})"
    );
    assert!(
        min >= MIN_FPS_FRACTION * FPS,
        "{min:.1} fps in a window (configured {FPS})"
    );
    assert!(
        samples.windows(2).all(|w| w[1].frames > w[0].frames),
        "frames stopped coming"
    );
}
