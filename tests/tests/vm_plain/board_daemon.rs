//! The real `sdid --backend auto` on the board emulator over the kernel's USB
//! stack (dummy_hcd + configfs + FunctionFS), inside the VM, on a private
//! dbus-daemon with the y4m output: auto picks the board, frames match what
//! the emulator streamed, the firmware's clamps are seen, unplug shows
//! "no signal" and DeviceUnavailable, replug resumes; `[board] on_unplug`
//! = "simulator" and "exit" behave as docs/install.md says; with a delay
//! on the LED path, `sdictl calibrate phase` (LS1 lit alone through
//! `[lights]`) makes the difference right again and is kept across
//! restarts; a region whose wells both fill is flagged saturated in sdid's
//! recording and kept out of separation.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::Stdio;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use sdi_tests::board_emulator::chip::SaturatedRegion;
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::dbus::{sdictl, Bus, Daemon};
use sdi_tests::light_rig::ScpiRig;
use sdi_tests::process::Reaped;
use sdi_tests::wait::{wait_for, wait_until};

const SERIAL: &str = "EMU0002";
const W: usize = 64;
const H: usize = 48;

/// What the y4m reader saw, in order: true = a "no signal" frame.
#[derive(Default)]
struct Seen {
    frames: Vec<(Instant, bool)>,
}

impl Seen {
    fn since(&self, t: Instant) -> impl Iterator<Item = bool> + '_ {
        self.frames.iter().filter(move |f| f.0 >= t).map(|f| f.1)
    }
}

/// The no-signal frame: grey stripes, luma only 40 and 60 (full range).
fn is_no_signal(y: &[u8]) -> bool {
    y.iter().all(|&v| v == 40 || v == 60) && y.contains(&40) && y.contains(&60)
}

struct Sdid {
    child: Reaped,
    address: String,
    seen: Arc<Mutex<Seen>>,
    frames: Arc<AtomicU64>,
    /// sdid's log lines so far (also passed on to the test's stderr).
    log: Arc<Mutex<Vec<String>>>,
}

impl Sdid {
    fn start(bus: &Bus, config: &Path) -> Self {
        Self::start_with(bus, config, &[])
    }

    fn start_with(bus: &Bus, config: &Path, args: &[&str]) -> Self {
        let mut child = Daemon::bare_command(bus, &[])
            .args(["--sink", "y4m", "--y4m-path", "-", "--config"])
            .arg(config)
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start sdid");
        let stdout = child.stdout.take().expect("stdout");
        let stderr = child.stderr.take().expect("stderr");
        let log = Arc::new(Mutex::new(Vec::new()));
        let lines = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{line}");
                lines.lock().unwrap().push(line);
            }
        });
        let seen = Arc::new(Mutex::new(Seen::default()));
        let frames = Arc::new(AtomicU64::new(0));
        let (s, n) = (seen.clone(), frames.clone());
        std::thread::spawn(move || read_y4m(stdout, &s, &n));
        let d = Self {
            child: Reaped(child),
            address: bus.address.clone(),
            seen,
            frames,
            log,
        };
        wait_until("sdid on the bus", Duration::from_secs(60), || {
            d.ctl(&["get", "mode"]).status.success()
        });
        d
    }

    fn ctl(&self, args: &[&str]) -> std::process::Output {
        sdictl(&self.address, args)
    }

    fn prop(&self, name: &str) -> serde_json::Value {
        let out = self.ctl(&["--json", "get", name]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
        v.as_object()
            .and_then(|o| o.values().next().cloned())
            .unwrap_or(v)
    }

    fn device_available(&self) -> bool {
        self.prop("stats")["device_available"]
            .as_bool()
            .expect("device_available in Stats")
    }

    fn snapshot(&self, path: &Path) -> std::process::Output {
        let _ = std::fs::remove_file(path);
        self.ctl(&["snapshot", path.to_str().unwrap()])
    }
}

fn read_y4m(out: impl Read, seen: &Mutex<Seen>, frames: &AtomicU64) {
    let mut r = BufReader::new(out);
    let mut header = String::new();
    if r.read_line(&mut header).is_err() {
        return;
    }
    let dim = |p: char| {
        header
            .split_whitespace()
            .find_map(|t| t.strip_prefix(p).and_then(|v| v.parse::<usize>().ok()))
            .unwrap_or(0)
    };
    let (w, h) = (dim('W'), dim('H'));
    assert!(header.contains("C444"), "{header}");
    let mut buf = vec![0u8; w * h * 3];
    loop {
        let mut tag = String::new();
        match r.read_line(&mut tag) {
            Ok(0) | Err(_) => return,
            Ok(_) => {}
        }
        if r.read_exact(&mut buf).is_err() {
            return;
        }
        let ns = is_no_signal(&buf[..w * h]);
        seen.lock().unwrap().frames.push((Instant::now(), ns));
        frames.fetch_add(1, Ordering::SeqCst);
    }
}

fn write_config(dir: &Path, name: &str, on_unplug: &str) -> std::path::PathBuf {
    write_config_for(dir, name, "auto", SERIAL, on_unplug)
}

fn write_config_for(
    dir: &Path,
    name: &str,
    backend: &str,
    serial: &str,
    on_unplug: &str,
) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(
        &p,
        format!(
            "backend = \"{backend}\"\nmode = \"raw\"\nframe_rate_hz = 30.0\n\
             # 60 % of a quad: more than the firmware's 20/64 cap\nexposure_us = 5000.0\n\
             [board]\nserial = \"{serial}\"\non_unplug = \"{on_unplug}\"\nroi = [0, 0, {W}, {H}]\n"
        ),
    )
    .unwrap();
    p
}

/// The snapshot's pixels (all but pixel 0, which carries the frame number)
/// equal one of the frames the emulator sent.
fn snapshot_matches(emu: &BoardEmulator, npy: &Path) -> bool {
    let f = std::fs::File::open(npy).expect("snapshot file");
    let (shape, data) = sdi_core::npy::read_f32(f).expect("npy");
    assert_eq!(shape, vec![H, W]);
    let s = emu.state.lock().unwrap();
    s.sent
        .iter()
        .any(|(_, dn)| dn.len() == data.len() && dn[1..] == data[1..])
}

/// The largest |difference| over the snapshot's pixels (but pixel 0) to
/// the closest frame the emulator sent, DN.
fn snapshot_error_dn(emu: &BoardEmulator, npy: &Path) -> f32 {
    let f = std::fs::File::open(npy).expect("snapshot file");
    let (_, data) = sdi_core::npy::read_f32(f).expect("npy");
    let s = emu.state.lock().unwrap();
    s.sent
        .iter()
        .filter(|(_, dn)| dn.len() == data.len())
        .map(|(_, dn)| {
            dn[1..]
                .iter()
                .zip(&data[1..])
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max)
        })
        .fold(f32::INFINITY, f32::min)
}

/// Takes snapshots until one is within `max_dn` of a frame sent or
/// `wait` is up; the last error.
fn snapshot_within(d: &Sdid, emu: &BoardEmulator, npy: &Path, max_dn: f32, wait: Duration) -> f32 {
    let t0 = Instant::now();
    loop {
        let out = d.snapshot(npy);
        assert!(out.status.success(), "{out:?}");
        let err = snapshot_error_dn(emu, npy);
        if err <= max_dn || t0.elapsed() > wait {
            return err;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn sdid_auto_picks_the_board_survives_unplug_and_follows_on_unplug() {
    if crate::GUEST.on_host() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let emu = BoardEmulator::start("sdi0", SERIAL).expect("gadget");
    wait_until("enumeration", Duration::from_secs(20), || {
        sdi_daemon::backend::board::board_attached().is_ok_and(|a| a)
    });
    let bus = Bus::start();

    // 1. no-signal (the default): auto picks the board
    let d = Sdid::start(&bus, &write_config(tmp.path(), "a.toml", "no-signal"));
    assert_eq!(d.prop("backend"), "opt8241");
    let device = d.prop("device");
    assert!(device.as_str().unwrap().contains(SERIAL), "{device}");
    wait_until("frames on y4m", Duration::from_secs(30), || {
        d.frames.load(Ordering::SeqCst) >= 10
    });
    // The emulator got the SDK's sequence; sdid never wrote a value the
    // firmware had to clamp: it clamped the duty cycle itself and says so.
    {
        let s = emu.state.lock().unwrap();
        assert_eq!(s.reg_value(0x5C4C) & 0x3F, 20, "intg_duty_cycle");
        // raw quads (output_mode 15), between the saturation probes' depth frames
        let modes = s.writes.iter().filter(|w| w.address == 0x5C25);
        assert_eq!(
            modes.map(|w| (w.kept >> 8) & 0xF).next(),
            Some(15),
            "raw quads"
        );
        assert!(s.reg_value(0x5882) & 0x3F_FFFF >= 60_000, "pix_cnt_max");
        for w in &s.writes {
            assert_eq!(w.written, w.kept, "firmware clamp hit: {w:?}");
        }
        assert!(s.stalled.is_empty(), "{:?}", s.stalled);
    }
    let state = d.prop("stats")["device_state"].clone();
    eprintln!("device_state: {state}");
    assert!(
        state.as_str().unwrap().contains("intg_duty_cycle"),
        "{state}"
    );
    // ExposureUs is what the board kept: 20/64 of a quad (1/120 s) = 2604 us.
    let exposure = d.prop("exposure-us").as_f64().unwrap();
    eprintln!("ExposureUs after clamp: {exposure}");
    assert!((exposure - 2604.17).abs() < 0.1, "{exposure}");
    // A faster frame rate shortens the quad (1/240 s at 60 Hz): the board
    // clamps the same exposure to 20/64 of it, and ExposureUs follows.
    let out = d.ctl(&["set", "frame-rate", "60"]);
    assert!(out.status.success(), "{out:?}");
    let exposure = d.prop("exposure-us").as_f64().unwrap();
    eprintln!("ExposureUs after clamp at 60 Hz: {exposure}");
    assert!((exposure - 1302.08).abs() < 0.1, "{exposure}");
    let out = d.ctl(&["set", "frame-rate", "30"]);
    assert!(out.status.success(), "{out:?}");

    // The setters' ranges are the chip's: 2 Hz needs a pix_cnt_max beyond
    // its 22 bits and is refused before any register is written, naming
    // the range; the board keeps streaming with the last good settings.
    let limits = d.prop("limits");
    eprintln!("Limits: {limits}");
    let fr = &limits["FrameRate"];
    assert!((fr[0].as_f64().unwrap() - 2.861).abs() < 1e-3, "{limits}");
    // (output_mode, 0x5C25, is the saturation probe's, written while streaming)
    let configuring = |emu: &BoardEmulator| {
        let s = emu.state.lock().unwrap();
        s.writes.iter().filter(|w| w.address != 0x5C25).count()
    };
    let writes_before = configuring(&emu);
    let out = d.ctl(&["set", "frame-rate", "2"]);
    assert!(!out.status.success(), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("2.86"), "{err}");
    assert_eq!(configuring(&emu), writes_before);
    assert_eq!(emu.state.lock().unwrap().reg_value(0x5880) & 1, 0, "tg_dis");
    let n = d.frames.load(Ordering::SeqCst);
    wait_until(
        "frames after a refused change",
        Duration::from_secs(10),
        || d.frames.load(Ordering::SeqCst) >= n + 5,
    );
    assert_eq!(d.prop("frame-rate").as_f64(), Some(30.0));

    // Temperatures are polled while streaming: tsensor, and tillum from
    // the CDK's sensor at 0x72 (the chip's default address reads nothing).
    wait_until("temperatures in Stats", Duration::from_secs(15), || {
        let s = d.prop("stats");
        s["board_temperature_c"].as_f64() == Some(35.0)
            && s["illumination_temperature_c"].as_f64() == Some(31.0)
    });
    let status = d.ctl(&["status"]);
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(text.contains("sensor 35 C, illumination 31 C"), "{text}");
    assert!(text.contains("frame rate 2.86"), "{text}");

    // An output overflow is seen at the next poll, counted in Stats, and
    // the frame it came with is dropped, which the log says; frames go on.
    emu.state.lock().unwrap().force_overflow = true;
    wait_until("an overflow in Stats", Duration::from_secs(15), || {
        d.prop("stats")["output_overflows"].as_u64() >= Some(1)
    });
    wait_until("the overflow in the log", Duration::from_secs(5), || {
        d.log
            .lock()
            .unwrap()
            .iter()
            .any(|l| l.contains("output overflow (op_overflow)") && l.contains("frame dropped"))
    });
    emu.state.lock().unwrap().force_overflow = false;
    let n = d.frames.load(Ordering::SeqCst);
    wait_until("frames after an overflow", Duration::from_secs(10), || {
        d.frames.load(Ordering::SeqCst) >= n + 5
    });

    let mut compared = 0;
    for i in 0..5 {
        let snap = tmp.path().join(format!("s{i}.npy"));
        let out = d.snapshot(&snap);
        assert!(out.status.success(), "{out:?}");
        assert!(
            snapshot_matches(&emu, &snap),
            "snapshot {i} differs from every frame sent"
        );
        compared += 1;
        std::thread::sleep(Duration::from_millis(100));
    }
    eprintln!("MEASURED: {compared} snapshots equal frames the emulator sent");

    saturated_wells_are_flagged_and_kept_out_of_separation(&emu, &d, tmp.path());

    // unplug mid-stream
    let t_unplug = Instant::now();
    emu.unplug().unwrap();
    let detect = wait_until("DeviceUnavailable", Duration::from_secs(20), || {
        !d.device_available()
    });
    eprintln!("MEASURED: unplug detected after {detect:?}");
    wait_until("no-signal frames", Duration::from_secs(20), || {
        d.seen
            .lock()
            .unwrap()
            .since(t_unplug)
            .filter(|&ns| ns)
            .count()
            >= 3
    });
    let out = d.snapshot(&tmp.path().join("gone.npy"));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("DeviceUnavailable") || err.contains("unavailable"),
        "{err}"
    );
    let out = d.ctl(&["set", "frame-rate", "20"]);
    assert!(!out.status.success(), "configure while unplugged: {out:?}");
    assert_eq!(d.prop("backend"), "opt8241");

    // plug back: frames resume
    let t_plug = Instant::now();
    emu.plug().unwrap();
    let resume = wait_until("board back", Duration::from_secs(30), || {
        d.device_available()
    });
    wait_until("frames after replug", Duration::from_secs(30), || {
        d.seen
            .lock()
            .unwrap()
            .since(t_plug)
            .filter(|&ns| !ns)
            .count()
            >= 5
    });
    eprintln!(
        "MEASURED: resumed (device available) {resume:?} after replug, first frames within {:?}",
        t_plug.elapsed()
    );
    let snap = tmp.path().join("back.npy");
    wait_until("snapshot after replug", Duration::from_secs(10), || {
        let out = d.snapshot(&snap);
        out.status.success() && snapshot_matches(&emu, &snap)
    });
    drop(d);

    // 2. on_unplug = "simulator": the simulator stands in, then the board again
    let d = Sdid::start(&bus, &write_config(tmp.path(), "b.toml", "simulator"));
    assert_eq!(d.prop("backend"), "opt8241");
    let t_unplug = Instant::now();
    emu.unplug().unwrap();
    let took = wait_until("simulator standing in", Duration::from_secs(20), || {
        d.prop("backend") == "sim"
    });
    eprintln!("MEASURED: simulator stood in after {took:?}");
    // Available again with the stand-in's first frame (Stats say no frames
    // until one comes: the backend switch is not a frame).
    wait_until("frames from the stand-in", Duration::from_secs(5), || {
        d.device_available()
    });
    let t_sim = Instant::now();
    wait_until("simulated frames", Duration::from_secs(20), || {
        d.seen
            .lock()
            .unwrap()
            .since(t_sim)
            .filter(|&ns| !ns)
            .count()
            >= 5
    });
    let n_ns = d.seen.lock().unwrap().since(t_sim).filter(|&ns| ns).count();
    assert_eq!(n_ns, 0, "no-signal frames while the simulator stands in");
    eprintln!("(unplug at {:?})", t_unplug.elapsed());
    let out = d.snapshot(&tmp.path().join("sim.npy"));
    assert!(out.status.success(), "{out:?}");
    emu.plug().unwrap();
    wait_until("board back", Duration::from_secs(30), || {
        d.prop("backend") == "opt8241"
    });
    let snap = tmp.path().join("back2.npy");
    wait_until(
        "board frames after the simulator",
        Duration::from_secs(10),
        || {
            let out = d.snapshot(&snap);
            out.status.success() && snapshot_matches(&emu, &snap)
        },
    );
    drop(d);

    // 3. on_unplug = "exit": sdid ends cleanly (status 0)
    let mut d = Sdid::start(&bus, &write_config(tmp.path(), "c.toml", "exit"));
    assert_eq!(d.prop("backend"), "opt8241");
    emu.unplug().unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = d.child.0.try_wait().unwrap() {
            break s;
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "sdid did not exit");
        std::thread::sleep(Duration::from_millis(50));
    };
    eprintln!(
        "MEASURED: sdid exited {:?} after unplug: {status}",
        t0.elapsed()
    );
    assert!(status.success(), "{status}");
    // Leave the gadget plugged in, as the emulator's teardown expects.
    emu.plug().unwrap();
    wait_until("re-enumeration", Duration::from_secs(20), || {
        sdi_daemon::backend::board::board_attached().is_ok_and(|a| a)
    });

    phase_calibration_fixes_a_delayed_led_path(&emu, &bus, tmp.path());
}

/// Part 4, the LED light 60 degrees of the modulation late: quad 0 alone reads
/// d cos 60 = d / 2. `sdictl calibrate phase` with LS1 lit alone (the
/// emulator's scene follows the function generator sdid drives) fits the
/// axis; the difference then matches what the emulator sent within the
/// 12-bit rounding, and again after a restart, from the store.
fn phase_calibration_fixes_a_delayed_led_path(emu: &BoardEmulator, bus: &Bus, dir: &Path) {
    let t0 = Instant::now();
    let delay_deg = 60.0f64;
    emu.state.lock().unwrap().led_delay_rad = delay_deg.to_radians();
    let scene = emu.state.clone();
    let rig = ScpiRig::start(move |ls1, ls2| scene.lock().unwrap().unlit = [!ls1, !ls2])
        .expect("light rig");
    let config = write_config(dir, "phase.toml", "no-signal");
    let mut text = std::fs::read_to_string(&config).unwrap();
    text += &format!(
        "[lights]\ndriver = \"scpi-tcp\"\naddress = \"{}\"\n",
        rig.address
    );
    std::fs::write(&config, text).unwrap();
    let state_dir = dir.join("state");
    let args = ["--state-dir", state_dir.to_str().unwrap()];
    let d = Sdid::start_with(bus, &config, &args);
    assert_eq!(d.prop("backend"), "opt8241");

    // Uncalibrated: quad 0 alone, half of every difference.
    let snap = dir.join("phase.npy");
    let wrong = snapshot_within(&d, emu, &snap, 1.0, Duration::from_secs(1));
    eprintln!("MEASURED: uncalibrated, {delay_deg} degrees late: snapshot off by up to {wrong} DN");
    assert!(
        wrong > 4.0,
        "quad 0 alone matched a delayed frame: {wrong} DN"
    );

    let out = d.ctl(&["--json", "calibrate", "phase", "--frames", "8"]);
    assert!(out.status.success(), "{out:?}");
    let reply: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    eprintln!("calibrate phase: {reply}");
    let angle = reply["angle_deg"].as_f64().expect("angle_deg");
    assert!((angle - delay_deg).abs() < 2.0, "{reply}");
    assert!(reply["coherence"].as_f64() > Some(0.9), "{reply}");
    assert!(
        !reply["lights"].as_str().unwrap_or("").is_empty(),
        "{reply}"
    );
    assert!(reply["stored"].as_str().is_some(), "{reply}");
    // sdid lit LS1 alone through the rig, then both again
    let log = rig.log.lock().unwrap().clone();
    assert!(log.iter().any(|c| c == "OUTPut2:STATe OFF"), "{log:?}");
    let right = snapshot_within(&d, emu, &snap, 1.0, Duration::from_secs(10));
    eprintln!("MEASURED: calibrated: snapshot off by up to {right} DN");
    assert!(right <= 1.0, "calibrated difference off by {right} DN");
    drop(d);

    // A restart reads the axis from the store.
    let stored = std::fs::read_to_string(state_dir.join("calibration.toml")).unwrap();
    assert!(stored.contains("[[phase]]"), "{stored}");
    let d = Sdid::start_with(bus, &config, &args);
    let right = snapshot_within(&d, emu, &snap, 1.0, Duration::from_secs(10));
    assert!(right <= 1.0, "after a restart: off by {right} DN");
    drop(d);
    emu.state.lock().unwrap().led_delay_rad = 0.0;
    eprintln!("MEASURED: phase calibration part took {:?}", t0.elapsed());
}

/// A board that enumerates in UVC mode (0451:9106): `sdid --backend
/// opt8241` sends the extension-unit request, the emulator re-enumerates as
/// 0451:9105, and sdid configures it and streams its frames.
#[test]
fn sdid_switches_a_uvc_mode_board_to_bulk_mode_and_streams() {
    if crate::GUEST.on_host() {
        return;
    }
    const UVC_SERIAL: &str = "EMU0003";
    let tmp = tempfile::tempdir().unwrap();
    let emu = BoardEmulator::start_uvc("sdiuvc", UVC_SERIAL).expect("gadget");
    wait_for("enumeration in UVC mode", Duration::from_secs(20), || {
        use rusb::UsbContext;
        let ctx = rusb::Context::new().ok()?;
        let devices = ctx.devices().ok()?;
        devices
            .iter()
            .any(|d| {
                d.device_descriptor()
                    .is_ok_and(|x| (x.vendor_id(), x.product_id()) == (0x0451, 0x9106))
            })
            .then_some(())
    });
    let bus = Bus::start();
    let t_start = Instant::now();
    let d = Sdid::start(
        &bus,
        &write_config_for(tmp.path(), "uvc.toml", "opt8241", UVC_SERIAL, "no-signal"),
    );
    assert_eq!(d.prop("backend"), "opt8241");
    let device = d.prop("device");
    assert!(device.as_str().unwrap().contains(UVC_SERIAL), "{device}");
    {
        let s = emu.state.lock().unwrap();
        // One SET_CUR (class, interface, OUT) of control 6 with one data
        // byte; FunctionFS shows wIndex as the function's interface number.
        assert_eq!(s.uvc_requests, vec![(0x21, 0x01, 0x0600, 0, vec![0])]);
        let switched = s
            .switched_to_bulk
            .expect("the emulator switched to bulk mode");
        eprintln!(
            "MEASURED: emulator back as 0451:9105 {:?} after sdid started",
            switched.duration_since(t_start)
        );
        assert!(s.stalled.is_empty(), "{:?}", s.stalled);
    }
    wait_until("frames on y4m", Duration::from_secs(30), || {
        d.seen
            .lock()
            .unwrap()
            .frames
            .iter()
            .filter(|f| !f.1)
            .count()
            >= 10
    });
    eprintln!(
        "MEASURED: 10 board frames {:?} after sdid started on a UVC-mode board",
        t_start.elapsed()
    );
    let snap = tmp.path().join("uvc.npy");
    wait_until(
        "a snapshot of a frame the emulator sent",
        Duration::from_secs(10),
        || {
            let out = d.snapshot(&snap);
            out.status.success() && snapshot_matches(&emu, &snap)
        },
    );
    assert!(d.device_available());
    drop(d);
}

/// Both wells full in a region (ambient light with the IR filter off):
/// the raw quads read 0 there, so only the chip's depth-output flag can
/// tell; sdid's frames (its recording) carry the pixels as saturated, no
/// other pixel, and separation marks them SATURATED.
fn saturated_wells_are_flagged_and_kept_out_of_separation(
    emu: &BoardEmulator,
    d: &Sdid,
    dir: &Path,
) {
    use sdi_core::separation::{unmix, UnmixOptions, Welford};
    use sdi_recording::{Record, RecordingReader};

    let region = SaturatedRegion {
        x: 16,
        y: 8,
        width: 16,
        height: 12,
    };
    emu.state.lock().unwrap().saturated_region = Some(region);
    let rec = dir.join("saturated.sdirec");
    let t0 = Instant::now();
    let out = d.ctl(&["record", rec.to_str().unwrap(), "--seconds", "2.5"]);
    assert!(out.status.success(), "{out:?}");
    emu.state.lock().unwrap().saturated_region = None;
    let mut frames = Vec::new();
    wait_until("the recording finished", Duration::from_secs(10), || {
        frames.clear();
        let Ok(mut r) = RecordingReader::open(&rec) else {
            return false;
        };
        let mut ended = false;
        while let Some(record) = r.next_record() {
            match record {
                Record::Frame { frame, .. } => frames.push(frame),
                Record::End { .. } => ended = true,
                Record::Dark { .. } => {}
            }
        }
        ended
    });
    let inside = |i: usize| region.contains(i % W, i / W);
    // Frames before the first probe (one every 30 frames) or before the
    // region reached a depth frame carry no flags yet.
    let flagged: Vec<_> = frames
        .iter()
        .filter(|f| {
            f.saturated
                .data
                .iter()
                .enumerate()
                .any(|(i, &s)| s != 0 && inside(i))
        })
        .collect();
    eprintln!(
        "MEASURED: {} of {} recorded frames flag the saturated region ({:?} for the recording)",
        flagged.len(),
        frames.len(),
        t0.elapsed()
    );
    assert!(flagged.len() >= 2, "no frame flags the saturated region");
    for f in &flagged {
        for (i, &s) in f.saturated.data.iter().enumerate() {
            assert_eq!(s != 0, inside(i), "pixel {i}: saturated = {s}");
        }
    }
    assert!(
        frames
            .last()
            .is_some_and(|f| flagged.iter().any(|g| g.sequence == f.sequence)),
        "the last frame is not flagged"
    );
    // The probe goes on while sdid streams: one in flight when the
    // recording ended has switched to depth output and switches back after
    // its one frame, so the last write is the raw output within a few
    // frames, and every switch to depth output is followed by one back.
    let output_modes = || -> Vec<u32> {
        let s = emu.state.lock().unwrap();
        s.writes
            .iter()
            .filter(|w| w.address == 0x5C25)
            .map(|w| (w.kept >> 8) & 0xF)
            .collect()
    };
    wait_until(
        "the board back in raw output after the probe in flight",
        Duration::from_secs(5),
        || output_modes().last() == Some(&15),
    );
    let modes = output_modes();
    assert!(modes.contains(&0), "no depth frame asked for: {modes:?}");
    assert!(
        !modes.windows(2).any(|w| w == [0, 0]),
        "two probes without the raw output between: {modes:?}"
    );
    let mut welford = Welford::new(W, H);
    for f in &flagged {
        welford.push(f).expect("push");
    }
    let h = sdi_core::sensor::SensorPreset::TiOpt8241.params().skellam();
    let sep = unmix(
        &welford.moments().expect("moments"),
        &h,
        UnmixOptions::default(),
    )
    .expect("unmix");
    let saturated = sdi_core::PixelFlags::SATURATED.bits();
    for (i, &f) in sep.flags.data.iter().enumerate() {
        assert_eq!(
            f & saturated != 0,
            inside(i),
            "separation flags of pixel {i}: {f:#x}"
        );
    }
}
