//! `sdictl view`'s benchmark (run by `tests/bench/view.sh`): sdid on the
//! simulator with a 640x480 sensor at 30 fps publishing y4m to ffplay (SDL's
//! dummy video driver: it decodes and converts every frame, shows none),
//! and `sdictl view` in headless Chromium on the same sdid. Prints the
//! frames the page drew per second (its own counter, `sdiView.shown`),
//! sdid's published rate, and the CPU share of one core of sdictl view,
//! ffplay and sdid over the window (utime + stime from /proc/PID/stat).

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use sdi_tests::cdp::Chromium;
use sdi_tests::dbus::{bin, Bus, Daemon};

const TI_SENSOR: &str = include_str!("../../../core/sensors/ti.toml");

fn cpu_ticks(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    // Fields after the command name (which may hold spaces): state is 3rd.
    let rest = &stat[stat.rfind(')').unwrap() + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap()
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn main() {
    let window_s: f64 = std::env::args()
        .nth(1)
        .map_or(10.0, |s| s.parse().expect("window seconds"));
    let dir = tempfile::tempdir().unwrap();
    let sensor = dir.path().join("vga.toml");
    let vga = TI_SENSOR
        .replace("width = 320", "width = 640")
        .replace("height = 240", "height = 480")
        .replace(
            "model = \"TI OPT8241\"",
            "model = \"TI OPT8241 at 640x480\"",
        );
    std::fs::write(&sensor, vga).unwrap();
    let fifo = dir.path().join("view.y4m");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();

    let ffplay = Killed(
        Command::new("ffplay")
            .args(["-loglevel", "error", "-f", "yuv4mpegpipe", "-i"])
            .arg(&fifo)
            .env("SDL_VIDEODRIVER", "dummy")
            .env("SDL_AUDIODRIVER", "dummy")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .expect("ffplay (apt-get install ffmpeg)"),
    );
    let bus = Bus::start();
    let mut cmd = Daemon::bare_command(&bus, &[]);
    cmd.args(["--backend", "sim", "--sink", "y4m", "--y4m-path"])
        .arg(&fifo)
        .args([
            "--frame-rate-hz",
            "30",
            "--mode",
            "bipolar-colour",
            "--sensor",
        ])
        .arg(&sensor)
        .stdout(Stdio::null());
    let d = Daemon::spawn(&bus, &mut cmd);
    d.wait_ready();

    let mut view = Killed(
        Command::new(bin("sdictl"))
            .args([
                "--bus-address",
                &bus.address,
                "view",
                "--no-open",
                "--out-dir",
            ])
            .arg(dir.path())
            .stdout(Stdio::piped())
            .spawn()
            .expect("sdictl view"),
    );
    let mut url = String::new();
    BufReader::new(view.0.stdout.take().unwrap())
        .read_line(&mut url)
        .unwrap();
    let Some(mut page) = Chromium::start(url.trim()) else {
        return;
    };
    page.wait_for(
        "!!(window.sdiView && sdiView.meta)",
        Duration::from_secs(60),
    );
    std::thread::sleep(Duration::from_secs(3));

    let pids = [
        ("sdictl view", view.0.id()),
        ("ffplay", ffplay.0.id()),
        ("sdid", d.pid()),
    ];
    let before: Vec<u64> = pids.iter().map(|(_, p)| cpu_ticks(*p)).collect();
    let shown0 = page.eval("sdiView.shown").as_f64().unwrap();
    let t0 = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(window_s));
    let shown1 = page.eval("sdiView.shown").as_f64().unwrap();
    let elapsed = t0.elapsed().as_secs_f64();
    let after: Vec<u64> = pids.iter().map(|(_, p)| cpu_ticks(*p)).collect();
    let meta = page.eval("sdiView.meta");
    let stats = sdi_tests::dbus::stats(&d);
    let hz = nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK)
        .unwrap()
        .unwrap() as f64;

    println!(
        "frame {}x{}, sdid publishes {:.1} fps",
        meta["width"],
        meta["height"],
        stats["fps"].as_f64().unwrap_or(f64::NAN)
    );
    println!(
        "page: {:.1} frames shown per second (sdiView.shown over {elapsed:.1} s), stream dropped {}",
        (shown1 - shown0) / elapsed,
        meta["dropped"]
    );
    for (i, (name, _)) in pids.iter().enumerate() {
        let pct = 100.0 * (after[i] - before[i]) as f64 / hz / elapsed;
        println!("{name}: {pct:.1}% of one core");
    }
}
