//! A page on 127.0.0.1 that opens the SDI camera with getUserMedia and
//! reports what it sees, for the browser VM tests.
//!
//! `--dump-dom` and `--virtual-time-budget` return before getUserMedia
//! resolves, so the browser keeps running and the page reports: it POSTs
//! JSON to `/report` (devices, the opened track, one frame drawn to a
//! canvas per second: size and mean colour) and polls `/cmd` for what to do
//! next (`data`: open the Y16 data node too). localhost is a secure
//! context, which getUserMedia needs.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

/// Chromium's flags for a headless test run, after `--headless`: no
/// sandbox or GPU, and nothing fetched or synced behind the test's back.
pub const CHROMIUM_QUIET: [&str; 7] = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
];

/// The page: everything it learns goes to `/report`.
pub const PAGE: &str = r#"<!doctype html><html><body><script>
const t0 = performance.now();
const post = (o) => { o.ms = Math.round(performance.now() - t0);
  return fetch('/report', {method: 'POST', body: JSON.stringify(o)}).catch(() => {}); };
const list = async () => (await navigator.mediaDevices.enumerateDevices())
  .map(d => ({kind: d.kind, label: d.label, id: d.deviceId}));
function stats(video, canvas) {
  const w = video.videoWidth, h = video.videoHeight;
  if (!w || !h) return null;
  canvas.width = w; canvas.height = h;
  const ctx = canvas.getContext('2d', {willReadFrequently: true});
  ctx.drawImage(video, 0, 0);
  const mean = (y0, y1) => { const d = ctx.getImageData(0, y0, w, y1 - y0).data;
    const m = [0, 0, 0]; for (let i = 0; i < d.length; i += 4) { m[0] += d[i]; m[1] += d[i+1]; m[2] += d[i+2]; }
    const n = d.length / 4; return m.map(v => v / n); };
  return {w, h, mean: mean(0, h), top: mean(0, Math.min(4, h))};
}
async function watch(name, constraints) {
  let frames = 0, opened = 0;
  const video = document.createElement('video');
  video.muted = true; video.playsInline = true;
  document.body.appendChild(video);
  const canvas = document.createElement('canvas');
  const count = () => { frames++; if (video.requestVideoFrameCallback) video.requestVideoFrameCallback(count); };
  async function open() {
    for (;;) {
      try {
        const stream = await navigator.mediaDevices.getUserMedia(constraints);
        const track = stream.getVideoTracks()[0];
        opened++;
        post({kind: 'opened', name, opened, label: track.label, settings: track.getSettings(),
              devices: await list()});
        track.onended = () => { post({kind: 'ended', name}); setTimeout(open, 1000); };
        track.onmute = () => post({kind: 'mute', name});
        track.onunmute = () => post({kind: 'unmute', name});
        video.srcObject = stream;
        await video.play();
        if (video.requestVideoFrameCallback) video.requestVideoFrameCallback(count);
        return track;
      } catch (e) {
        post({kind: 'error', name, error: String(e), error_name: e.name});
        await new Promise(r => setTimeout(r, 2000));
      }
    }
  }
  let track = await open();
  setInterval(() => {
    const s = stats(video, canvas);
    const t = video.srcObject && video.srcObject.getVideoTracks()[0];
    post({kind: 'frame', name, frames, opened, stats: s,
          state: t ? t.readyState : 'none', muted: t ? t.muted : null});
  }, 1000);
}
(async () => {
  try {
    post({kind: 'devices-before', devices: await list()});
    // Labels are empty until a getUserMedia was granted: open any camera,
    // then pick the SDI camera by its label.
    // A camera taken from PipeWire may be listed only once the camera
    // portal answered: retry while no camera is found.
    let any = null;
    for (let i = 0; !any; i++) {
      try { any = await navigator.mediaDevices.getUserMedia({video: true}); }
      catch (e) {
        if (e.name !== 'NotFoundError' || i >= 240) throw e;
        post({kind: 'retry', error: String(e)});
        await new Promise(r => setTimeout(r, 2000));
      }
    }
    any.getTracks().forEach(t => t.stop());
    const devices = await list();
    post({kind: 'devices', devices});
    const cam = devices.find(d => d.kind === 'videoinput' && d.label.startsWith('SDI camera'));
    if (!cam) { post({kind: 'error', name: 'view', error: 'no SDI camera listed'}); return; }
    watch('view', {video: {deviceId: {exact: cam.id}, width: 640, height: 480}});
    for (;;) {
      await new Promise(r => setTimeout(r, 1000));
      const cmd = await (await fetch('/cmd')).text();
      if (cmd === 'data') {
        const data = (await list()).find(d => d.kind === 'videoinput' && d.label.startsWith('SDI data'));
        if (!data) post({kind: 'error', name: 'data', error: 'SDI data not listed'});
        else watch('data', {video: {deviceId: {exact: data.id}}});
      }
    }
  } catch (e) { post({kind: 'error', name: 'page', error: String(e), error_name: e.name}); }
})();
</script></body></html>
"#;

/// How long a browser may take from its start to the page's first report.
/// That is the browser's own start under TCG (profile, caches, JIT), not
/// SDI's: 48-59 s for Chromium and Firefox ESR alone on a 2-core AMD EPYC;
/// a CI machine runs a second guest and the host's tests beside it.
pub const PAGE_LOAD: Duration = Duration::from_secs(420);

/// Reports the page POSTed, in order, with the time each arrived.
pub type Reports = Arc<Mutex<Vec<(Instant, Value)>>>;

/// The local page server on 127.0.0.1 (a thread; lives with the process).
pub struct PageServer {
    pub url: String,
    pub reports: Reports,
    commands: Arc<Mutex<Vec<String>>>,
}

fn handle(
    mut s: TcpStream,
    reports: &Reports,
    commands: &Mutex<Vec<String>>,
) -> std::io::Result<()> {
    s.set_read_timeout(Some(Duration::from_secs(30)))?;
    let mut r = BufReader::new(s.try_clone()?);
    let mut line = String::new();
    r.read_line(&mut line)?;
    let mut parts = line.split_whitespace();
    let (method, path) = (
        parts.next().unwrap_or("").to_owned(),
        parts.next().unwrap_or("").to_owned(),
    );
    let mut length = 0usize;
    loop {
        let mut h = String::new();
        if r.read_line(&mut h)? == 0 || h == "\r\n" || h == "\n" {
            break;
        }
        if let Some((k, v)) = h.split_once(':') {
            if k.eq_ignore_ascii_case("content-length") {
                length = v.trim().parse().unwrap_or(0);
            }
        }
    }
    let mut body = vec![0; length];
    r.read_exact(&mut body)?;
    let (ctype, reply) = match (method.as_str(), path.as_str()) {
        ("POST", "/report") => {
            if let Ok(v) = serde_json::from_slice::<Value>(&body) {
                reports.lock().expect("reports").push((Instant::now(), v));
            }
            ("text/plain", String::new())
        }
        ("GET", "/cmd") => {
            let mut c = commands.lock().expect("commands");
            let next = if c.is_empty() {
                String::new()
            } else {
                c.remove(0)
            };
            ("text/plain", next)
        }
        _ => ("text/html", PAGE.to_owned()),
    };
    write!(
        s,
        "HTTP/1.1 200 OK\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n{reply}",
        reply.len()
    )?;
    s.flush()
}

impl PageServer {
    pub fn start() -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1");
        let port = listener.local_addr().expect("local addr").port();
        let reports: Reports = Arc::default();
        let commands: Arc<Mutex<Vec<String>>> = Arc::default();
        let (r, c) = (reports.clone(), commands.clone());
        std::thread::spawn(move || {
            for s in listener.incoming().flatten() {
                let (r, c) = (r.clone(), c.clone());
                std::thread::spawn(move || {
                    let _ = handle(s, &r, &c);
                });
            }
        });
        Self {
            url: format!("http://127.0.0.1:{port}/"),
            reports,
            commands,
        }
    }

    /// Queues a command for the page's next `/cmd` poll.
    pub fn command(&self, cmd: &str) {
        self.commands.lock().expect("commands").push(cmd.to_owned());
    }

    /// Forgets the reports so far (a new browser starts).
    pub fn clear(&self) {
        self.reports.lock().expect("reports").clear();
    }

    /// The first report from index `from` on that `pred` accepts, polling
    /// until `limit`; panics with the reports seen (and `what`) otherwise.
    /// Returns (its index, the report).
    pub fn wait_for(
        &self,
        what: &str,
        from: usize,
        limit: Duration,
        pred: impl Fn(&Value) -> bool,
    ) -> (usize, Value) {
        let t0 = Instant::now();
        loop {
            {
                let r = self.reports.lock().expect("reports");
                if let Some((i, (_, v))) =
                    r.iter().enumerate().skip(from).find(|(_, (_, v))| pred(v))
                {
                    return (i, v.clone());
                }
                if t0.elapsed() > limit {
                    let tail: Vec<String> = r
                        .iter()
                        .skip(r.len().saturating_sub(15))
                        .map(|(_, v)| v.to_string())
                        .collect();
                    panic!(
                        "{what}: not within {limit:?}; last reports:\n{}",
                        tail.join("\n")
                    );
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Number of reports so far.
    pub fn len(&self) -> usize {
        self.reports.lock().expect("reports").len()
    }

    /// True before the first report.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The page's first view frame with stats: the page must load (its first
    /// report) within [`PAGE_LOAD`] and draw a frame within `limit` after
    /// that. Panics with the page's reports and `failure()` (browser and
    /// other logs) when the page reports an error or either step times out.
    pub fn first_view_frame(
        &self,
        name: &str,
        limit: Duration,
        failure: impl Fn() -> String,
    ) -> Value {
        let t0 = Instant::now();
        while self.is_empty() {
            assert!(
                t0.elapsed() < PAGE_LOAD,
                "{name}: the page did not load in {PAGE_LOAD:?} (the browser's own start)\n{}",
                failure()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
        let loaded = self.reports.lock().expect("reports")[0].0;
        eprintln!(
            "{name}: the page loaded {:.1} s after the wait began",
            loaded.saturating_duration_since(t0).as_secs_f64()
        );
        loop {
            if let Some(v) = self
                .of_kind("frame")
                .into_iter()
                .find(|v| v["name"] == "view" && frames_of(v) > 0 && !v["stats"].is_null())
            {
                return v;
            }
            if let Some(e) = self.of_kind("error").first() {
                panic!("{name}: the page failed: {e}\n{}", failure());
            }
            assert!(
                loaded.elapsed() < limit,
                "{name}: no frame of the SDI camera in {limit:?} after the page loaded; \
                 page retries {}\n\
                 the page's reports (seconds after the wait began):\n{}\n{}",
                self.of_kind("retry").len(),
                self.timeline(t0),
                failure()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// The first `opened` and `devices` reports: the track opened is the SDI
    /// camera (label starting with `label`) at 640x480, and so is `first`,
    /// the first frame drawn. Returns the device list.
    pub fn assert_opened_view(&self, name: &str, label: &str, first: &Value) -> Value {
        let opened = self
            .of_kind("opened")
            .into_iter()
            .next()
            .expect("opened before frames");
        let devices = self.of_kind("devices").into_iter().next().expect("devices");
        eprintln!(
            "{name}: opened {opened}\n{name}: devices {}",
            devices["devices"]
        );
        assert!(
            opened["label"]
                .as_str()
                .is_some_and(|l| l.starts_with(label)),
            "{name}: opened {opened}, not {label}"
        );
        assert_eq!(opened["settings"]["width"], 640, "{name}: {opened}");
        assert_eq!(opened["settings"]["height"], 480, "{name}: {opened}");
        assert_eq!(first["stats"]["w"], 640, "{name}: {first}");
        assert_eq!(first["stats"]["h"], 480, "{name}: {first}");
        devices
    }

    /// Every report of `kind` (for the log).
    /// The reports so far, one line each with its arrival in seconds after
    /// `since`; a `frame` report only where it differs from the previous one
    /// of its track in what matters (frames counted, stats, state), so a
    /// stalled page reads as a few lines.
    pub fn timeline(&self, since: Instant) -> String {
        let reports = self.reports.lock().expect("reports");
        let mut last_frame: std::collections::HashMap<String, String> = Default::default();
        let mut lines = Vec::new();
        for (at, v) in reports.iter() {
            let t = at.saturating_duration_since(since).as_secs_f64();
            let line = if v["kind"] == "frame" {
                let key = format!(
                    "frames>0={} stats={} state={} muted={}",
                    frames_of(v) > 0,
                    !v["stats"].is_null(),
                    v["state"],
                    v["muted"]
                );
                let name = v["name"].as_str().unwrap_or("").to_owned();
                if last_frame.get(&name) == Some(&key) {
                    continue;
                }
                last_frame.insert(name.clone(), key.clone());
                format!("frame {name} (page {} ms) {key}", v["ms"])
            } else {
                let mut short = v.clone();
                if let Some(o) = short.as_object_mut() {
                    o.remove("devices");
                }
                short.to_string()
            };
            lines.push(format!("{t:7.1} s  {line}"));
        }
        lines.join("\n")
    }

    pub fn of_kind(&self, kind: &str) -> Vec<Value> {
        self.reports
            .lock()
            .expect("reports")
            .iter()
            .filter(|(_, v)| v["kind"] == kind)
            .map(|(_, v)| v.clone())
            .collect()
    }
}

/// A browser process group, killed on drop.
pub struct Browser {
    child: Child,
    pub log: PathBuf,
    pub started: Instant,
}

impl Browser {
    /// Spawns `cmd` in its own process group, so that all its processes go
    /// with it. Without `session_bus`, it gets no session bus it could lose
    /// when the test tears down.
    fn spawn(mut cmd: Command, log: &Path, session_bus: Option<&str>) -> Self {
        let out = std::fs::File::create(log).expect("browser log");
        let err = out.try_clone().expect("browser log");
        match session_bus {
            Some(address) => cmd.env("DBUS_SESSION_BUS_ADDRESS", address),
            None => cmd.env_remove("DBUS_SESSION_BUS_ADDRESS"),
        };
        cmd.env("DBUS_SYSTEM_BUS_ADDRESS", "unix:path=/nonexistent")
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err);
        std::os::unix::process::CommandExt::process_group(&mut cmd, 0);
        let started = Instant::now();
        let child = cmd.spawn().expect("spawn browser");
        Self {
            child,
            log: log.to_owned(),
            started,
        }
    }

    /// Headless Chromium on `url` with the camera permission granted by the
    /// fake UI (the real devices, not the fake one); as root it needs
    /// `--no-sandbox`. The other flags keep it off the (closed) network.
    pub fn chromium(url: &str, dir: &Path) -> Self {
        Self::spawn(
            Self::chromium_command(url, dir),
            &dir.join("chromium.log"),
            None,
        )
    }

    /// Headless Chromium taking cameras from PipeWire through the camera
    /// portal (`--enable-features=WebRtcPipeWireCamera`), started as a
    /// client of a PipeWire session (`session`: the private one of a
    /// `pipewire::Session`, or a user's own), on its bus (the portal is on
    /// that bus). `dir` must be writable by the session's user.
    pub fn chromium_pipewire(url: &str, dir: &Path, session: &crate::pipewire::Clients) -> Self {
        let mut cmd = Self::chromium_args(session.command("chromium"), url, dir);
        cmd.args([
            "--enable-features=WebRtcPipeWireCamera",
            // WebRTC's portal and PipeWire steps, in the log.
            "--enable-logging=stderr",
            "--vmodule=camera_portal=1,pipewire_session=1,video_capture_pipewire=1",
        ]);
        Self::spawn(
            cmd,
            &dir.join("chromium-pipewire.log"),
            Some(session.bus_address()),
        )
    }

    fn chromium_command(url: &str, dir: &Path) -> Command {
        Self::chromium_args(Command::new("chromium"), url, dir)
    }

    /// Chromium's arguments and profile (HOME: `dir`) added to `cmd`.
    fn chromium_args(mut cmd: Command, url: &str, dir: &Path) -> Command {
        let profile = dir.join("chromium-profile");
        let _ = std::fs::remove_dir_all(&profile);
        cmd.arg("--headless=new")
            .args(CHROMIUM_QUIET)
            .args([
                "--use-fake-ui-for-media-stream",
                "--autoplay-policy=no-user-gesture-required",
                // A child process that has not heard from the browser in 15 s
                // quits, and under TCG with sdid busy beside it the network
                // service did ("Terminating current process after 15 seconds
                // with no connection"): the page never loaded. Chromium's own
                // browser tests raise this timeout for loaded machines too.
                "--ipc-connection-timeout=120",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(url)
            .env("HOME", dir);
        cmd
    }

    /// Headless Firefox ESR with a test profile: no permission prompt, the
    /// real devices (not the fake stream), no network chatter.
    pub fn firefox(url: &str, dir: &Path) -> Self {
        let profile = dir.join("firefox-profile");
        let _ = std::fs::remove_dir_all(&profile);
        std::fs::create_dir_all(&profile).expect("firefox profile");
        let prefs = [
            ("media.navigator.permission.disabled", "true"),
            ("media.navigator.streams.fake", "false"),
            ("media.autoplay.default", "0"),
            ("media.autoplay.blocking_policy", "0"),
            ("browser.shell.checkDefaultBrowser", "false"),
            ("browser.aboutwelcome.enabled", "false"),
            ("datareporting.policy.dataSubmissionEnabled", "false"),
            ("toolkit.telemetry.reportingpolicy.firstRun", "false"),
            ("app.update.enabled", "false"),
            ("network.captive-portal-service.enabled", "false"),
            ("network.connectivity-service.enabled", "false"),
            ("browser.safebrowsing.update.enabled", "false"),
            ("extensions.update.enabled", "false"),
            ("browser.startup.homepage_override.mstone", "\"ignore\""),
        ];
        let user_js: String = prefs
            .iter()
            .map(|(k, v)| format!("user_pref(\"{k}\", {v});\n"))
            .collect();
        std::fs::write(profile.join("user.js"), user_js).expect("user.js");
        let mut cmd = Command::new("firefox-esr");
        cmd.args(["--headless", "--no-remote", "--profile"])
            .arg(&profile)
            .arg(url)
            .env("HOME", dir)
            .env("MOZ_DISABLE_CONTENT_SANDBOX", "1");
        Self::spawn(cmd, &dir.join("firefox.log"), None)
    }

    /// Each fatal error in the browser's log (a failed CHECK of Chromium or
    /// WebRTC ends a process with "FATAL"), with the lines after it that
    /// say which check failed and where.
    pub fn fatal_errors(&self) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines
            .iter()
            .enumerate()
            .filter(|(_, l)| l.contains(":FATAL:"))
            .flat_map(|(i, _)| lines[i..lines.len().min(i + 12)].iter().copied())
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// The lines of the browser's log that contain `pattern`.
    pub fn log_lines(&self, pattern: &str) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        text.lines()
            .filter(|l| l.contains(pattern))
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// The last lines of the browser's log.
    pub fn log_tail(&self) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(30)..].join("\n")
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let pg = self.child.id().to_string();
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{pg}")])
            .status();
        let _ = self.child.wait();
    }
}

/// The colour `stats[key]` ("mean", "top" ...) of a page's frame report.
pub fn stats_rgb(v: &Value, key: &str) -> Option<[f64; 3]> {
    let a = v["stats"][key].as_array()?;
    Some([
        a.first()?.as_f64()?,
        a.get(1)?.as_f64()?,
        a.get(2)?.as_f64()?,
    ])
}

/// A frame report of the page's view track.
pub fn is_view_frame(v: &Value) -> bool {
    v["kind"] == "frame" && v["name"] == "view"
}

/// How many frames a frame report says its track has shown.
pub fn frames_of(v: &Value) -> u64 {
    v["frames"].as_u64().unwrap_or(0)
}

/// A live view frame report whose mean colour is within `tolerance` codes
/// (per channel) of `expected`.
pub fn view_frame_like(v: &Value, expected: [f64; 3], tolerance: f64) -> bool {
    is_view_frame(v)
        && v["state"] == "live"
        && stats_rgb(v, "mean").is_some_and(|m| crate::clients::off_by(m, expected) < tolerance)
}
