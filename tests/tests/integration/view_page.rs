//! `sdictl view` against `sdid --backend sim` on a private bus: the guard
//! (no token, a wrong token, a foreign Origin or Host get 403 and change
//! nothing, over HTTP and WebSocket), and the page in headless Chromium
//! (frames as `sdictl snapshot` renders them, the mode picker, the controls
//! bounded by sdid's `Limits`, a control and its typed error, histogram and
//! probe against numpy, separation's two images). `SDI_VIEW_SCREENSHOT=PATH`
//! also saves a screenshot of the page.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use sdi_tests::cdp::Chromium;
use sdi_tests::dbus::{bin, Bus, Daemon};
use sdi_tests::require_dbus;
use serde_json::Value;

/// Debian's python3, where python3-numpy installs numpy.
const PYTHON: &str = "/usr/bin/python3";

/// A running `sdictl view` and where it serves.
pub(crate) struct View {
    child: Child,
    /// Kept open: sdictl stops when its stdout is closed.
    _stdout: BufReader<std::process::ChildStdout>,
    pub(crate) url: String,
    pub(crate) port: u16,
    pub(crate) token: String,
}

impl View {
    pub(crate) fn start(d: &Daemon, out_dir: &Path) -> Self {
        Self::start_with(d, out_dir, &[])
    }

    /// With `env` set for sdictl (test hooks such as `SDI_VIEW_TIMEOUT_MS`).
    pub(crate) fn start_with(d: &Daemon, out_dir: &Path, env: &[(&str, &str)]) -> Self {
        Self::spawn(
            Command::new(bin("sdictl"))
                .args(Self::args(d, out_dir))
                .envs(env.iter().copied()),
        )
    }

    /// sdictl's arguments for a viewer of `d` that opens no browser and
    /// prints its URL first, saving into `out_dir`.
    pub(crate) fn args(d: &Daemon, out_dir: &Path) -> Vec<std::ffi::OsString> {
        [
            "--bus-address",
            &d.address,
            "view",
            "--no-open",
            "--print-url",
            "--out-dir",
        ]
        .iter()
        .map(Into::into)
        .chain([out_dir.as_os_str().to_owned()])
        .collect()
    }

    /// Starts `cmd` (an `sdictl view --print-url`: its first line is the URL).
    pub(crate) fn spawn(cmd: &mut Command) -> Self {
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start sdictl view");
        let mut line = String::new();
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        stdout.read_line(&mut line).unwrap();
        let url = line.trim().to_owned();
        let rest = url.strip_prefix("http://127.0.0.1:").expect(&url);
        let port = rest.split('/').next().unwrap().parse().unwrap();
        let token = url.split("token=").nth(1).unwrap().to_owned();
        Self {
            child,
            _stdout: stdout,
            url,
            port,
            token,
        }
    }

    /// Sends a raw HTTP/1.1 request; returns the status code.
    pub(crate) fn status_of(&self, request: &str) -> u16 {
        self.send(request).1
    }

    /// Sends a raw HTTP/1.1 request; returns the connection, read up to
    /// the status code, and the status code.
    fn send(&self, request: &str) -> (TcpStream, u16) {
        let mut s = TcpStream::connect(("127.0.0.1", self.port)).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        s.write_all(request.as_bytes()).unwrap();
        let mut head = [0u8; 12];
        s.read_exact(&mut head).unwrap();
        let text = String::from_utf8_lossy(&head);
        let status = text[9..12].parse().expect(&text);
        (s, status)
    }

    /// Sends a raw HTTP/1.1 request with `Connection: close`; returns the
    /// status code and the body.
    pub(crate) fn response_to(&self, request: &str) -> (u16, String) {
        let (mut s, status) = self.send(request);
        let mut rest = Vec::new();
        let _ = s.read_to_end(&mut rest);
        let rest = String::from_utf8_lossy(&rest).into_owned();
        let body = rest
            .split_once("\r\n\r\n")
            .map_or("", |(_, b)| b)
            .to_owned();
        (status, body)
    }

    /// `POST /api/PATH` with the token, Host, Origin and the JSON `body`.
    pub(crate) fn post(&self, path: &str, body: &str) -> (u16, String) {
        let host = format!("127.0.0.1:{}", self.port);
        self.response_to(&format!(
            "POST /api/{path}?token={} HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n\
             Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            self.token,
            body.len()
        ))
    }

    /// `GET /api/status` with the token and Host.
    pub(crate) fn status(&self) -> (u16, String) {
        self.response_to(&format!(
            "GET /api/status?token={} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nConnection: close\r\n\r\n",
            self.token, self.port
        ))
    }
}

impl Drop for View {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn set_exposure(host: &str, origin: Option<&str>, path: &str) -> String {
    let body = r#"{"setting":"exposure-us","value":"3333"}"#;
    let origin = origin.map_or(String::new(), |o| format!("Origin: {o}\r\n"));
    format!(
        "POST {path} HTTP/1.1\r\nHost: {host}\r\n{origin}Content-Type: application/json\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
}

fn websocket(host: &str, origin: &str, path: &str) -> String {
    format!(
        "GET {path} HTTP/1.1\r\nHost: {host}\r\nOrigin: {origin}\r\nUpgrade: websocket\r\n\
         Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\
         Sec-WebSocket-Version: 13\r\n\r\n"
    )
}

fn exposure_us(d: &Daemon) -> f64 {
    let out = d.ctl(&["get", "exposure-us"]);
    let text = String::from_utf8_lossy(&out.stdout);
    text.trim().parse().expect(&text)
}

/// sdid's `Limits` property: setter name on the bus -> [min, max].
fn limits(d: &Daemon) -> Value {
    let out = d.ctl(&["--json", "get", "limits"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    v["Limits"].clone()
}

#[test]
fn without_token_own_host_and_origin_everything_is_403_and_nothing_changes() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let v = View::start(&d, dir.path());
    let before = exposure_us(&d);
    let host = format!("127.0.0.1:{}", v.port);
    let origin = format!("http://{host}");
    let good = format!("/api/set?token={}", v.token);
    let wrong = format!("/api/set?token={}", "0".repeat(32));
    let cases = [
        ("no token", set_exposure(&host, Some(&origin), "/api/set")),
        ("wrong token", set_exposure(&host, Some(&origin), &wrong)),
        (
            "foreign origin",
            set_exposure(&host, Some("http://evil.example"), &good),
        ),
        ("no origin", set_exposure(&host, None, &good)),
        (
            "foreign host",
            set_exposure(&format!("evil.example:{}", v.port), Some(&origin), &good),
        ),
        (
            "status without token",
            format!("GET /api/status HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"),
        ),
        (
            "page for a foreign host",
            format!(
                "GET /?token={} HTTP/1.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n",
                v.token
            ),
        ),
        ("websocket without token", websocket(&host, &origin, "/ws")),
        (
            "websocket from a foreign origin",
            websocket(
                &host,
                "http://evil.example",
                &format!("/ws?token={}", v.token),
            ),
        ),
        (
            "websocket for a foreign host",
            websocket("evil.example", &origin, &format!("/ws?token={}", v.token)),
        ),
    ];
    for (what, request) in &cases {
        assert_eq!(v.status_of(request), 403, "{what}");
    }
    assert_eq!(exposure_us(&d), before, "a refused request changed sdid");
    // The same requests with token, Host and Origin are served.
    let ws = websocket(&host, &origin, &format!("/ws?token={}", v.token));
    assert_eq!(v.status_of(&ws), 101);
    assert_eq!(v.status_of(&set_exposure(&host, Some(&origin), &good)), 200);
    assert_eq!(exposure_us(&d), 3333.0);
}

/// numpy's view of `values`: histogram over (lo, hi) with `bins` bins,
/// mean and var(ddof=1) of `series`. None: no numpy (skipped).
fn numpy_stats(npy: &Path, bins: usize, lo: f64, hi: f64, series: &[f64]) -> Option<Value> {
    let script = r#"
import json, sys, numpy as np
a = np.load(sys.argv[1])
bins, lo, hi = int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
s = np.array(json.loads(sys.argv[5]), dtype=np.float64)
h, _ = np.histogram(a[np.isfinite(a)].astype(np.float64), bins, range=(lo, hi))
print(json.dumps({"counts": h.tolist(), "mean": float(s.mean()), "var": float(s.var(ddof=1))}))
"#;
    let probe = Command::new(PYTHON).args(["-c", "import numpy"]).output();
    if !probe.is_ok_and(|o| o.status.success()) {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_VM",
            format_args!("no numpy (apt-get install python3-numpy)"),
        );
        return None;
    }
    let out = Command::new(PYTHON)
        .args(["-c", script])
        .arg(npy)
        .args([bins.to_string(), lo.to_string(), hi.to_string()])
        .arg(serde_json::to_string(series).unwrap())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(serde_json::from_slice(&out.stdout).unwrap())
}

#[test]
fn the_page_shows_controls_and_measures_what_sdid_publishes() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--mode", "bipolar-colour"]);
    let dir = tempfile::tempdir().unwrap();
    let v = View::start(&d, dir.path());
    let Some(mut page) = Chromium::start(&v.url) else {
        return;
    };
    let long = Duration::from_secs(60);
    page.wait_for("!!(window.sdiView && sdiView.meta && sdiView.status)", long);

    // Probe a pixel, then slow sdid to one frame per 10 s: the frame the
    // call returns with stays the latest while the page and snapshots read it.
    page.eval("(() => { ws.send(JSON.stringify({probe: [40, 30]})); return true; })()");
    page.wait_for(
        "!!(sdiView.meta.probe && sdiView.meta.probe.values.length >= 5)",
        long,
    );
    let out = d.ctl(&["set", "frame-rate", "0.1"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let png = dir.path().join("snap.png");
    let npy = dir.path().join("snap.npy");
    for p in [&png, &npy] {
        let out = d.ctl(&["snapshot", p.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let snap = sdi_tests::npy_file::read_npy(&npy);
    // The page's frame is the snapshot's: the same signed DN at the probe.
    let probe_last = format!("{}", snap.1[30 * snap.0[1] + 40]);
    page.wait_for(
        &format!("sdiView.meta.probe.values.at(-1) === {probe_last}"),
        long,
    );
    let meta = page.eval("sdiView.meta");
    let (w, h) = (
        meta["width"].as_u64().unwrap(),
        meta["height"].as_u64().unwrap(),
    );
    let pixels = page.eval(
        "Array.from(document.getElementById('view').getContext('2d')\
         .getImageData(0, 0, sdiView.meta.width, sdiView.meta.height).data)",
    );
    let rgb = image::open(&png).unwrap().to_rgb8();
    assert_eq!((rgb.width() as u64, rgb.height() as u64), (w, h));
    let page_px: Vec<u8> = pixels
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as u8)
        .collect();
    let worst = rgb
        .as_raw()
        .chunks_exact(3)
        .zip(page_px.chunks_exact(4))
        .flat_map(|(a, b)| (0..3).map(move |c| a[c].abs_diff(b[c])))
        .max()
        .unwrap();
    // The page draws sdid's own RGB (RGBA with opaque alpha): exact, and
    // within 1 level should a browser ever round through premultiplied alpha.
    assert!(
        worst <= 1,
        "page and snapshot differ by up to {worst} levels"
    );

    // Histogram and probe against numpy on the same frame and series.
    let hist = &meta["histogram"];
    let counts: Vec<u64> = serde_json::from_value(hist["counts"].clone()).unwrap();
    let series: Vec<f64> = serde_json::from_value(meta["probe"]["values"].clone()).unwrap();
    let (lo, hi) = (hist["lo"].as_f64().unwrap(), hist["hi"].as_f64().unwrap());
    if let Some(np) = numpy_stats(&npy, counts.len(), lo, hi, &series) {
        let np_counts: Vec<u64> = serde_json::from_value(np["counts"].clone()).unwrap();
        // numpy bins a value on an edge by its own rounding: allow a value
        // or two to sit in the neighbouring bin.
        let moved: u64 = counts
            .iter()
            .zip(&np_counts)
            .map(|(a, b)| a.abs_diff(*b))
            .sum();
        assert!(moved <= 4, "histogram {counts:?} vs numpy {np_counts:?}");
        let m = &meta["probe"]["moments"];
        let rel = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
        assert!(
            rel(m["mean"].as_f64().unwrap(), np["mean"].as_f64().unwrap()),
            "{m} vs {np}"
        );
        assert!(
            rel(m["variance"].as_f64().unwrap(), np["var"].as_f64().unwrap()),
            "{m} vs {np}"
        );
    }
    let out = d.ctl(&["set", "frame-rate", "30"]);
    assert!(out.status.success());

    // Clicking a mode switches sdid, and the page then shows its frames.
    page.eval("document.getElementById('mode-depth-edge').click(), true");
    sdi_tests::wait::wait_until("sdid in depth-edge", long, || {
        String::from_utf8_lossy(&d.ctl(&["get", "mode"]).stdout).trim() == "depth-edge"
    });
    page.wait_for("sdiView.meta.mode === 'depth-edge'", long);

    // The controls are the settings sdictl serves (sdi_api's table), each
    // under its name with its error line, a choice with its names.
    let controls = page.eval(
        "sdiView.status.settings.map((s) => { const e = document.getElementById(s.name); \
         return [s.name, !!e && !!document.getElementById(s.name + '_error') && \
         (s.kind !== 'choice' || [...e.options].map((o) => o.value).join() === s.choices.join())]; })",
    );
    let controls = controls.as_array().cloned().unwrap_or_default();
    let settings = sdi_api::Setting::all().filter(|&s| s != sdi_api::Setting::Mode);
    assert_eq!(controls.len(), settings.count(), "{controls:?}");
    for c in &controls {
        assert_eq!(c[1], true, "the page's control for {}", c[0]);
    }

    // The numeric inputs carry sdid's Limits as min and max, shown under
    // each; a control sets the property; a value outside still goes to sdid
    // and shows its typed error in place.
    let limits = limits(&d);
    for (input, key) in [
        ("exposure-us", "ExposureUs"),
        ("frame-rate", "FrameRate"),
        ("modulation-hz", "ModulationHz"),
    ] {
        let bounds = page.eval(&format!(
            "(() => {{ const e = document.getElementById('{input}'); \
             return [Number(e.min), Number(e.max), e.min !== '' && e.max !== '', \
             document.getElementById('{input}_valid').textContent]; }})()"
        ));
        assert_eq!(bounds[2], true, "{input} has no min/max: {bounds}");
        let (min, max) = (limits[key][0].as_f64(), limits[key][1].as_f64());
        assert!(min.is_some() && max.is_some(), "{key} in {limits}");
        assert_eq!(bounds[0].as_f64(), min, "{input} min vs Limits {limits}");
        assert_eq!(bounds[1].as_f64(), max, "{input} max vs Limits {limits}");
        assert!(
            bounds[3].as_str().unwrap().starts_with("valid "),
            "{input}: {bounds}"
        );
    }
    page.eval(
        "(() => { const e = document.getElementById('exposure-us'); e.value = '2500'; \
         e.dispatchEvent(new Event('change')); return true; })()",
    );
    sdi_tests::wait::wait_until("ExposureUs 2500", long, || exposure_us(&d) == 2500.0);
    page.eval(
        "(() => { const e = document.getElementById('exposure-us'); e.value = '1e9'; \
         e.dispatchEvent(new Event('change')); return true; })()",
    );
    page.wait_for(
        "document.getElementById('exposure-us_error').textContent.includes('OutOfRange')",
        long,
    );
    assert_eq!(exposure_us(&d), 2500.0);

    // Separation: I+ and I- side by side.
    page.eval("document.getElementById('mode-separation').click(), true");
    page.wait_for(
        "sdiView.meta.mode === 'separation' && sdiView.meta.images.length === 3 \
         && getComputedStyle(document.getElementById('channels')).display === 'flex' \
         && document.getElementById('i_plus').width > 0 && document.getElementById('i_minus').width > 0 \
         && document.getElementById('i_plus_err').textContent.includes('e-')",
        long,
    );
    if let Some(path) = std::env::var_os("SDI_VIEW_SCREENSHOT") {
        page.eval(
            "(() => { ws.send(JSON.stringify({region: [20, 20, 24, 24]})); return true; })()",
        );
        page.wait_for(
            "!!(sdiView.meta.region && sdiView.meta.region.report.frames >= 20)",
            long,
        );
        page.screenshot(Path::new(&path));
    }
}

/// `StreamFrames` takes only the writing end of a pipe or socket, at most
/// two per connection and four in all, and writes frames in
/// `sdi_api::frame_stream`'s format.
#[test]
fn stream_frames_checks_its_descriptor_and_streams_frames() {
    use sdi_api::frame_stream::{FrameHeader, HEADER_BYTES};
    use zbus::zvariant::Fd;
    require_dbus!();
    let bus = Bus::start();
    let _d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let rt = sdi_tests::dbus::runtime();
    rt.block_on(async {
        let conn = bus.connect().await;
        let cam = sdi_api::Camera1Proxy::new(&conn).await.unwrap();
        let other = bus.connect().await;
        let cam2 = sdi_api::Camera1Proxy::new(&other).await.unwrap();
        let invalid =
            |r: Result<(), sdi_api::SdiError>| matches!(r, Err(sdi_api::SdiError::InvalidFd(_)));
        let file = std::fs::File::create(dir.path().join("f")).unwrap();
        assert!(invalid(cam.stream_frames(Fd::from(&file)).await));
        let (pipe_r, _pipe_w) = nix::unistd::pipe().unwrap();
        assert!(invalid(cam.stream_frames(Fd::from(&pipe_r)).await));
        let mut ours = Vec::new();
        for c in [&cam, &cam, &cam2, &cam2] {
            let (a, b) = std::os::unix::net::UnixStream::pair().unwrap();
            c.stream_frames(Fd::from(&b)).await.unwrap();
            ours.push(a);
        }
        let third = bus.connect().await;
        let cam = sdi_api::Camera1Proxy::new(&third).await.unwrap();
        let (_a, b) = std::os::unix::net::UnixStream::pair().unwrap();
        assert!(matches!(
            cam.stream_frames(Fd::from(&b)).await,
            Err(sdi_api::SdiError::Busy(_))
        ));
        let mut head = [0u8; HEADER_BYTES];
        ours[0].read_exact(&mut head).unwrap();
        let h = FrameHeader::decode(&head).unwrap();
        assert_eq!((h.mode.as_str(), h.colormap.as_str()), ("raw", "diverging"));
        let mut body = vec![0u8; h.body_bytes()];
        ours[0].read_exact(&mut body).unwrap();
        ours[0].read_exact(&mut head).unwrap();
        assert!(FrameHeader::decode(&head).unwrap().sequence > h.sequence);
        // A closed stream frees its place.
        drop(ours.pop());
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        let (_a, b) = std::os::unix::net::UnixStream::pair().unwrap();
        while cam.stream_frames(Fd::from(&b)).await.is_err() {
            assert!(
                std::time::Instant::now() < deadline,
                "a closed stream kept its place"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
}

/// Issue 43 (1): `sdictl view` opens a 0600 file in the user's runtime
/// directory that carries the token, never the URL: no process's command
/// line (xdg-open's, the browser's) shows the token, and the page opened
/// from the file works and drops the token from its address.
#[test]
fn the_token_is_on_no_command_line_only_in_a_private_file() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let (runtime, fake_bin, record) = (
        dir.path().join("run"),
        dir.path().join("bin"),
        dir.path().join("xdg-open.argv"),
    );
    for p in [&runtime, &fake_bin] {
        std::fs::create_dir(p).unwrap();
        std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o700)).unwrap();
    }
    // A fake xdg-open: records its arguments, NUL-separated.
    let xdg_open = fake_bin.join("xdg-open");
    std::fs::write(
        &xdg_open,
        "#!/bin/sh\nprintf '%s\\0' \"$@\" > \"$SDI_TEST_RECORD.tmp\"\n\
         mv \"$SDI_TEST_RECORD.tmp\" \"$SDI_TEST_RECORD\"\n",
    )
    .unwrap();
    std::fs::set_permissions(&xdg_open, std::fs::Permissions::from_mode(0o700)).unwrap();
    let path = format!(
        "{}:{}",
        fake_bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut child = Command::new(bin("sdictl"))
        .args(["--bus-address", &d.address, "view", "--out-dir"])
        .arg(dir.path())
        .env("PATH", path)
        .env("DISPLAY", ":99")
        .env("XDG_RUNTIME_DIR", &runtime)
        .env("SDI_TEST_RECORD", &record)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start sdictl view");
    struct Kill(Child);
    impl Drop for Kill {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let _child = Kill(child);
    let mut first_line = String::new();
    stdout.read_line(&mut first_line).unwrap();
    sdi_tests::wait::wait_until("xdg-open ran", Duration::from_secs(30), || record.exists());
    let argv: Vec<String> = std::fs::read(&record)
        .unwrap()
        .split(|&b| b == 0)
        .filter(|a| !a.is_empty())
        .map(|a| String::from_utf8_lossy(a).into_owned())
        .collect();
    assert!(
        argv.len() == 1 && !argv[0].contains("token"),
        "xdg-open was given {argv:?}"
    );
    let file = Path::new(argv[0].strip_prefix("file://").unwrap_or(&argv[0]));
    assert!(file.starts_with(&runtime), "{file:?} not in {runtime:?}");
    let meta = std::fs::metadata(file).unwrap();
    assert_eq!(meta.mode() & 0o777, 0o600, "{file:?}");
    assert_eq!(meta.uid(), nix::unistd::getuid().as_raw(), "{file:?}");
    let html = std::fs::read_to_string(file).unwrap();
    let token: String = html
        .split("token=")
        .nth(1)
        .unwrap_or("")
        .chars()
        .take_while(char::is_ascii_hexdigit)
        .collect();
    assert_eq!(token.len(), 32, "no token in {html}");
    assert!(!first_line.contains(&token), "stdout: {first_line}");
    // No command line on the machine carries the token.
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        if let Ok(cmdline) = std::fs::read(entry.path().join("cmdline")) {
            let cmdline = String::from_utf8_lossy(&cmdline);
            assert!(
                !cmdline.contains(&token),
                "{:?}: {cmdline}",
                entry.file_name()
            );
        }
    }
    // The page served with that token works, and from the file too.
    let port: u16 = html
        .split("http://127.0.0.1:")
        .nth(1)
        .and_then(|r| r.split('/').next())
        .and_then(|p| p.parse().ok())
        .expect(&html);
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(
        s,
        "GET /api/status?token={token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = String::new();
    let _ = s.read_to_string(&mut reply);
    assert!(reply.starts_with("HTTP/1.1 200"), "{reply}");
    let Some(mut page) = Chromium::start(&format!("file://{}", file.display())) else {
        return;
    };
    let long = Duration::from_secs(60);
    page.wait_for("!!(window.sdiView && sdiView.status && sdiView.meta)", long);
    let href = page.eval("location.href");
    assert!(
        !href.as_str().unwrap_or("").contains(&token),
        "the address keeps the token: {href}"
    );
}

/// Issue 43 (2): a value with a NUL (not a D-Bus string) is refused with
/// 400 before it reaches the bus, and the viewer's controls keep working.
#[test]
fn a_nul_in_a_control_value_is_refused_and_the_controls_keep_working() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let v = View::start(&d, dir.path());
    for (setting, value) in [("mode", "raw\\u0000"), ("colormap", "\\u0000")] {
        let body = format!(r#"{{"setting":"{setting}","value":"{value}"}}"#);
        let (status, reply) = v.post("set", &body);
        assert_eq!(status, 400, "{body}: {reply}");
        assert!(reply.contains("NUL"), "{body}: {reply}");
    }
    let (status, reply) = v.status();
    assert_eq!(status, 200, "after a NUL: {reply}");
    let (status, reply) = v.post("set", r#"{"setting":"mode","value":"depth-edge"}"#);
    assert_eq!(status, 200, "{reply}");
}

/// Issue 43 (7): simultaneous snapshots each get a file of their own.
#[test]
fn concurrent_snapshots_get_distinct_files() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let v = View::start(&d, dir.path());
    sdi_tests::wait::wait_until("a first frame", Duration::from_secs(30), || {
        v.post("snapshot", r#"{"format":"png"}"#).0 == 200
    });
    let replies: Vec<(u16, String)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..12)
            .map(|_| s.spawn(|| v.post("snapshot", r#"{"format":"npy"}"#)))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut paths = std::collections::BTreeSet::new();
    for (status, reply) in &replies {
        assert_eq!(*status, 200, "{reply}");
        let v: Value = serde_json::from_str(reply).expect(reply);
        let path = v["path"].as_str().expect(reply).to_owned();
        assert!(
            std::fs::metadata(&path).is_ok_and(|m| m.len() > 0),
            "{path} is empty"
        );
        paths.insert(path);
    }
    assert_eq!(paths.len(), 12, "{replies:?}");
}
