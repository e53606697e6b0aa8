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
struct View {
    child: Child,
    url: String,
    port: u16,
    token: String,
}

impl View {
    fn start(d: &Daemon, out_dir: &Path) -> Self {
        let mut child = Command::new(bin("sdictl"))
            .args([
                "--bus-address",
                &d.address,
                "view",
                "--no-open",
                "--out-dir",
            ])
            .arg(out_dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start sdictl view");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let url = line.trim().to_owned();
        let rest = url.strip_prefix("http://127.0.0.1:").expect(&url);
        let port = rest.split('/').next().unwrap().parse().unwrap();
        let token = url.split("token=").nth(1).unwrap().to_owned();
        Self {
            child,
            url,
            port,
            token,
        }
    }

    /// Sends a raw HTTP/1.1 request; returns the status code.
    fn status_of(&self, request: &str) -> u16 {
        let mut s = TcpStream::connect(("127.0.0.1", self.port)).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        s.write_all(request.as_bytes()).unwrap();
        let mut head = [0u8; 12];
        s.read_exact(&mut head).unwrap();
        let text = String::from_utf8_lossy(&head);
        text[9..12].parse().expect(&text)
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
            "page without token",
            format!("GET / HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"),
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
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
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
