//! sdid as root against hostile devices on the board's USB IDs, inside the
//! VM: one boot runs every mode of the emulator's
//! [`HostileMode`] in turn. Between modes the genuine emulated board comes
//! back, and sdid must stream it again. During each attack another client
//! reads the `Stats` property every 100 ms and sets the colormap every
//! 500 ms, a call answered through the frame loop (each answered within
//! 1 s more than the bus daemon's own reply just before it, however long
//! the device keeps the frame back; one late reply per kind and mode is
//! the guest's scheduling, not sdid, if it is not a stall), sdid's
//! VmRSS stays within [`RSS_GROWTH_BOUND_KIB`] of its size before the first
//! attack, and its log has at most [`MAX_LOG_LINES`] lines for the mode (one
//! line per cause, never one per frame or per attempt).

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use sdi_api::Camera1Proxy;
use sdi_tests::board_emulator::hostile::{HostileBoard, HostileMode};
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::wait::wait_until;

const SERIAL: &str = "EMU0031";
/// How long each hostile device stays plugged in once sdid has reached its
/// misbehaviour ([`HostileBoard::engaged`]): longer than the board
/// backend's frame wait (2 s): a stream of bad frames ends in its error
/// sooner (after 8 unusable transfers), and so does a request left to NAK
/// (1 s after the third attempt, when the device counts as engaged).
const ATTACK: Duration = Duration::from_millis(2500);
/// The longest wait for sdid to reach the misbehaviour.
const ENGAGE_TIMEOUT: Duration = Duration::from_secs(20);
/// A reply slower than this, beyond the bus daemon's reply to `GetId`
/// just before it (the host's load), is late. sdid held behind the device
/// (its 2 s frame wait, a NAKing request) makes every call of the hold
/// late: several per mode at these cadences. A TCG guest beside a busy
/// host delays one now and then (quiet: slowest 0.9 s; beside two other
/// builds: one SetColormap of 1.33 s with GetId 0.09 s), so one late
/// reply per kind and mode is allowed if it is shorter than [`STALLED`].
const MAX_REPLY: Duration = Duration::from_secs(1);
/// A reply this much slower than the GetId before it is a stall, even alone.
const STALLED: Duration = Duration::from_millis(2500);
/// sdid's VmRSS may grow at most this much over its size before the first
/// attack: the stream's buffers are a few frames of the configured size
/// (24 KiB here), so holding even half of one 16 MiB hostile frame fails.
const RSS_GROWTH_BOUND_KIB: u64 = 8 * 1024;
/// Log lines sdid may write from a hostile device's arrival until the
/// genuine board streams again: the loss of the board, the cause, the
/// no-signal notice and the return, with room for one cause more.
const MAX_LOG_LINES: usize = 6;

/// sdid's stderr, line by line, with when each line came.
type Log = Arc<Mutex<Vec<(Instant, String)>>>;

/// One property read by the other client: when it started, how long it took,
/// and the Stats it returned; and how long the bus daemon itself took to
/// answer just before (GetId), which tells a VM starved of CPU by its host
/// from a slow sdid.
struct Probe {
    at: Instant,
    took: Duration,
    stats: Option<sdi_api::Stats>,
    bus_took: Duration,
}

/// One call through sdid's frame loop (SetColormap, answered at the next
/// frame, a failed capture, or 0.5 s into a silence): when it started, how
/// long it took, whether it succeeded, and the bus daemon's GetId time just
/// before on the same connection (as [`Probe::bus_took`]).
struct Call {
    at: Instant,
    took: Duration,
    ok: bool,
    bus_took: Duration,
}

type Commands = Arc<Mutex<Vec<Call>>>;

/// Reads `Stats` every 100 ms (no property cache: a real round trip) and,
/// concurrently on its own connection, sets the colormap every 500 ms,
/// until `stop`.
fn probe_loop(
    address: String,
    probes: Arc<Mutex<Vec<Probe>>>,
    commands: Commands,
    stop: Arc<AtomicBool>,
) {
    sdi_tests::dbus::runtime().block_on(async move {
        let proxy = |conn: zbus::Connection| async move {
            Camera1Proxy::builder(&conn)
                .cache_properties(zbus::proxy::CacheProperties::No)
                .build()
                .await
                .expect("proxy")
        };
        let reader_conn = sdi_tests::dbus::connect(&address).await;
        let bus = zbus::fdo::DBusProxy::new(&reader_conn)
            .await
            .expect("bus proxy");
        let reader = proxy(reader_conn.clone()).await;
        let commander_conn = sdi_tests::dbus::connect(&address).await;
        let commander_bus = zbus::fdo::DBusProxy::new(&commander_conn)
            .await
            .expect("bus proxy");
        let commander = proxy(commander_conn).await;
        let reads = async {
            while !stop.load(Ordering::SeqCst) {
                let bus_took = get_id_took(&bus).await;
                let at = Instant::now();
                let stats = tokio::time::timeout(Duration::from_secs(10), reader.stats())
                    .await
                    .ok()
                    .and_then(Result::ok);
                probes.lock().unwrap().push(Probe {
                    at,
                    took: at.elapsed(),
                    stats,
                    bus_took,
                });
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        };
        let calls = async {
            while !stop.load(Ordering::SeqCst) {
                let bus_took = get_id_took(&commander_bus).await;
                let at = Instant::now();
                let ok = tokio::time::timeout(
                    Duration::from_secs(30),
                    commander.set_colormap("diverging"),
                )
                .await
                .is_ok_and(|r| r.is_ok());
                commands.lock().unwrap().push(Call {
                    at,
                    took: at.elapsed(),
                    ok,
                    bus_took,
                });
                tokio::time::sleep(Duration::from_millis(500)).await;
            }
        };
        tokio::join!(reads, calls);
    });
}

/// How long the bus daemon took to answer `GetId` (10 s at the most).
async fn get_id_took(bus: &zbus::fdo::DBusProxy<'_>) -> Duration {
    let t = Instant::now();
    let _ = tokio::time::timeout(Duration::from_secs(10), bus.get_id()).await;
    t.elapsed()
}

/// What one mode's attack measured, asserted once every mode ran.
struct Report {
    mode: HostileMode,
    /// The slowest Stats read, and the GetId just before it.
    slowest: Duration,
    bus_then: Duration,
    /// The slowest SetColormap call, and the GetId just before it.
    slowest_command: Duration,
    bus_then_command: Duration,
    /// Late replies ([`MAX_REPLY`] beyond their GetId): reads, calls.
    late: (usize, usize),
    rss_max_kib: u64,
    lines: Vec<String>,
}

/// VmRSS of `pid`, KiB.
fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .expect("VmRSS of sdid")
}

/// CPU time (user + system) of `pid`, clock ticks.
fn cpu_ticks(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("stat of sdid");
    // Fields after the command name in parentheses; utime and stime are
    // fields 14 and 15.
    let rest = &stat[stat.rfind(')').expect("comm") + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    f[11].parse::<u64>().unwrap_or(0) + f[12].parse::<u64>().unwrap_or(0)
}

fn latest(probes: &Mutex<Vec<Probe>>) -> Option<sdi_api::Stats> {
    probes
        .lock()
        .unwrap()
        .iter()
        .rev()
        .find_map(|p| p.stats.clone())
}

/// Waits until sdid streams the genuine board: available, and 5 frames
/// more than `from` counted.
fn wait_streaming(probes: &Mutex<Vec<Probe>>, what: &str) -> Duration {
    let from = latest(probes).map_or(0, |s| s.frames);
    wait_until(what, Duration::from_secs(60), || {
        latest(probes).is_some_and(|s| s.device_available && s.frames >= from + 5)
    })
}

#[test]
fn sdid_survives_hostile_boards_and_streams_the_genuine_one_again() {
    if crate::GUEST.on_host() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let genuine = BoardEmulator::start("sdig", SERIAL).expect("gadget");
    wait_until("enumeration", Duration::from_secs(20), || {
        sdi_daemon::backend::board::board_attached().is_ok_and(|a| a)
    });
    let bus = Bus::start();
    let config = tmp.path().join("sdid.toml");
    // No serial: the udev rule starts sdid for any device on the IDs.
    std::fs::write(
        &config,
        "backend = \"opt8241\"\nmode = \"raw\"\nframe_rate_hz = 30.0\n\
         [board]\non_unplug = \"no-signal\"\nroi = [0, 0, 64, 48]\n",
    )
    .unwrap();
    let mut child = Daemon::bare_command(&bus, &[])
        .args(["--sink", "y4m", "--y4m-path", "-", "--config"])
        .arg(&config)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start sdid");
    let stderr = child.stderr.take().expect("stderr");
    let pid = child.id();
    let log: Log = Log::default();
    {
        let log = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { return };
                eprintln!("sdid: {line}");
                log.lock().unwrap().push((Instant::now(), line));
            }
        });
    }
    let mut d = Daemon {
        child,
        address: bus.address.clone(),
    };
    d.wait_ready();
    let probes = Arc::new(Mutex::new(Vec::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let commands = Commands::default();
    let prober = {
        let (a, p, c, s) = (
            bus.address.clone(),
            probes.clone(),
            commands.clone(),
            stop.clone(),
        );
        std::thread::spawn(move || probe_loop(a, p, c, s))
    };
    wait_streaming(&probes, "the genuine board streaming");
    let rss_before_kib = rss_kib(pid);
    let (cpu0, t_cpu) = (cpu_ticks(pid), Instant::now());
    std::thread::sleep(ATTACK);
    let cpu_streaming_percent = (cpu_ticks(pid) - cpu0) as f64 / t_cpu.elapsed().as_secs_f64();
    eprintln!(
        "MEASURED: sdid before the attacks, streaming the genuine board: VmRSS {rss_before_kib} KiB, \
         CPU {cpu_streaming_percent:.0} %"
    );

    let mut report = Vec::new();
    // SDI_HOSTILE_MODES=a,b runs only those modes (when hunting one).
    let only = std::env::var("SDI_HOSTILE_MODES").ok();
    let modes = HostileMode::ALL.into_iter().filter(|m| {
        only.as_deref()
            .is_none_or(|o| o.split(',').any(|n| n == m.name()))
    });
    for (i, mode) in modes.enumerate() {
        eprintln!("== {}: the genuine board leaves", mode.name());
        genuine.unplug().unwrap();
        wait_until("sdid sees the board go", Duration::from_secs(20), || {
            latest(&probes).is_some_and(|s| !s.device_available)
        });
        let t0 = Instant::now();
        let cpu0 = cpu_ticks(pid);
        eprintln!("== {}: the hostile device arrives", mode.name());
        let hostile = HostileBoard::start(&format!("evil{i}"), SERIAL, mode).expect("hostile");
        let mut rss_max_kib = 0;
        let mut engaged_at = None;
        while engaged_at.is_none_or(|t: Instant| t.elapsed() < ATTACK) {
            if engaged_at.is_none() && hostile.engaged() {
                engaged_at = Some(Instant::now());
            }
            assert!(
                engaged_at.is_some() || t0.elapsed() < ENGAGE_TIMEOUT,
                "{}: sdid never reached the device's misbehaviour",
                mode.name()
            );
            if let Ok(Some(status)) = d.child.try_wait() {
                panic!("{}: sdid ended: {status}", mode.name());
            }
            rss_max_kib = rss_max_kib.max(rss_kib(pid));
            std::thread::sleep(Duration::from_millis(100));
        }
        let cpu_ticks_attack = cpu_ticks(pid) - cpu0;
        let attack = t0.elapsed();
        let engaged_after = engaged_at.map(|t| t - t0).unwrap_or_default();
        let transfers = hostile.transfers.load(Ordering::SeqCst);
        eprintln!("== {}: the hostile device leaves", mode.name());
        let left_after = t0.elapsed();
        drop(hostile);
        eprintln!("== {}: the genuine board comes back", mode.name());
        let t_plug = Instant::now();
        genuine.plug().unwrap();
        let recovery = wait_streaming(&probes, &format!("{}: streaming again", mode.name()));
        rss_max_kib = rss_max_kib.max(rss_kib(pid));
        let lines: Vec<String> = log
            .lock()
            .unwrap()
            .iter()
            .filter(|(t, _)| *t >= t0)
            .map(|(t, l)| format!("{:6.2} s  {l}", (*t - t0).as_secs_f64()))
            .collect();
        let (n_probes, slowest, bus_then, late_reads) = {
            let p = probes.lock().unwrap();
            let window: Vec<&Probe> = p.iter().filter(|p| p.at >= t0 && p.at < t_plug).collect();
            let worst = window.iter().max_by_key(|p| p.took);
            (
                window.len(),
                worst.map(|p| p.took).unwrap_or_default(),
                worst.map(|p| p.bus_took).unwrap_or_default(),
                window
                    .iter()
                    .filter(|p| p.took > MAX_REPLY + p.bus_took)
                    .count(),
            )
        };
        let (n_calls, failed_calls, slowest_command, bus_then_command, slowest_at, late_calls) = {
            let c = commands.lock().unwrap();
            let window: Vec<&Call> = c.iter().filter(|c| c.at >= t0 && c.at < t_plug).collect();
            let worst = window.iter().max_by_key(|c| c.took);
            (
                window.len(),
                window.iter().filter(|c| !c.ok).count(),
                worst.map(|c| c.took).unwrap_or_default(),
                worst.map(|c| c.bus_took).unwrap_or_default(),
                worst.map(|c| c.at - t0).unwrap_or_default(),
                window
                    .iter()
                    .filter(|c| c.took > MAX_REPLY + c.bus_took)
                    .count(),
            )
        };
        let cpu_percent = cpu_ticks_attack as f64 / attack.as_secs_f64();
        eprintln!(
            "MEASURED: {}: {n_probes} Stats reads, slowest {slowest:?} \
             (the bus daemon's GetId just before: {bus_then:?}) \
             ({n_calls} SetColormap calls through the frame loop, {failed_calls} failed: slowest \
             {slowest_command:?} from {slowest_at:.2?} into the attack, GetId just before \
             {bus_then_command:?}); late replies: {late_reads} reads, {late_calls} calls; VmRSS max {rss_max_kib} KiB \
             (+{} KiB); CPU {cpu_percent:.0} %; {} log lines; {transfers} hostile transfers \
             (engaged after {engaged_after:.2?}, the device left after {left_after:.2?}); \
             streaming again {recovery:?} after the genuine board came back",
            mode.name(),
            rss_max_kib.saturating_sub(rss_before_kib),
            lines.len()
        );
        for l in &lines {
            eprintln!("    | {l}");
        }
        report.push(Report {
            mode,
            slowest,
            bus_then,
            slowest_command,
            bus_then_command,
            late: (late_reads, late_calls),
            rss_max_kib,
            lines,
        });
        assert!(
            n_probes >= 5,
            "{}: only {n_probes} Stats reads",
            mode.name()
        );
        assert!(
            n_calls >= 2,
            "{}: only {n_calls} SetColormap calls",
            mode.name()
        );
    }
    stop.store(true, Ordering::SeqCst);
    let _ = prober.join();
    for Report {
        mode,
        slowest,
        bus_then,
        slowest_command,
        bus_then_command,
        late: (late_reads, late_calls),
        rss_max_kib,
        lines,
    } in &report
    {
        assert!(
            *late_reads <= 1 && *slowest < STALLED + *bus_then,
            "{}: {late_reads} late Stats reads, the slowest {slowest:?} (the bus daemon's \
             GetId just before: {bus_then:?})",
            mode.name()
        );
        assert!(
            *late_calls <= 1 && *slowest_command < STALLED + *bus_then_command,
            "{}: {late_calls} late SetColormap calls, the slowest {slowest_command:?} (the bus \
             daemon's GetId just before: {bus_then_command:?})",
            mode.name()
        );
        assert!(
            *rss_max_kib <= rss_before_kib + RSS_GROWTH_BOUND_KIB,
            "{}: VmRSS {rss_max_kib} KiB, {rss_before_kib} KiB before the attacks",
            mode.name()
        );
        assert!(
            lines.len() <= MAX_LOG_LINES,
            "{}: {} log lines:\n{}",
            mode.name(),
            lines.len(),
            lines.join("\n")
        );
    }
    drop(d);
}
