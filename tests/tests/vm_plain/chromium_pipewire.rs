//! Headless Chromium takes the SDI camera from sdid's PipeWire sink, no
//! kernel module involved (issue 17), in the VM: `pipewire`, `wireplumber`,
//! the camera portal (`xdg-desktop-portal` with the permission store; see
//! `sdi_tests::pipewire::CameraPortal`) and `sdid --sink pipewire` on one
//! private session bus; Chromium with `--enable-features=WebRtcPipeWireCamera`
//! asks the portal for the camera, gets PipeWire's socket from it and lists
//! "SDI camera (MODE)". The page (`sdi_tests::browser`) opens it at 640x480,
//! a frame drawn to a canvas has the mode's mean colour (`sdictl snapshot`,
//! letterboxed, with a tolerance for YUV to RGB), and `sdictl set-mode`
//! changes what it sees. Across a restart of sdid the track survives (the
//! camera process sdid started keeps the node) and shows the new frames.
//! Then the module is loaded and sdid restarts with `--sink auto`: it feeds
//! the loopback nodes and the same camera (issue 32), the page keeps
//! reading and sees a mode switch, and ffmpeg reads the loopback node.

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use serde_json::Value;

use sdi_tests::browser::{frames_of, stats_rgb, view_frame_like, Browser, PageServer};
use sdi_tests::capture;
use sdi_tests::clients::{self, off_by, DATA_LABEL, PMD, VIEW_LABEL};
use sdi_tests::loopback;
use sdi_tests::pipewire::{self, CameraPortal, Session};
use sdi_tests::process::{stdout_of, Reaped};

const TOLERANCE: f64 = 12.0;
/// The loopback nodes of the module-loaded phase.
const VIEW_NR: u32 = 40;
const DATA_NR: u32 = 41;

/// `sdid --sink pipewire` on the simulator, in `session`.
struct Sdid {
    _child: Reaped,
    address: String,
}

impl Sdid {
    fn start(session: &Session) -> Self {
        Self::start_with(session, &["--sink", "pipewire"])
    }

    /// `sdid --sink auto` with the loopback nodes' labels (the module
    /// loaded): the loopback sink, and the PipeWire camera beside it.
    fn start_auto(session: &Session) -> Self {
        let config = session.dir.path().join("sdid.toml");
        std::fs::write(
            &config,
            format!("[output]\nlabel = \"{VIEW_LABEL}\"\ndata_label = \"{DATA_LABEL}\"\n"),
        )
        .expect("write sdid.toml");
        let config = config.display().to_string();
        Self::start_with(session, &["--sink", "auto", "--config", &config])
    }

    fn start_with(session: &Session, sink: &[&str]) -> Self {
        // Appended to: the camera process of the first sdid keeps writing here.
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(session.dir.path().join("sdid.log"))
            .expect("sdid log");
        let child = sdi_tests::sdid_command::SdidCommand::client_of(session)
            .bus(&session.bus.address)
            .sim()
            .args(["--sensor", PMD.name])
            .args(sink)
            .args(["--frame-rate-hz", "15", "--exposure-us", "2000"])
            .command()
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("spawn sdid");
        let mut d = Self {
            _child: Reaped(child),
            address: session.bus.address.clone(),
        };
        // The limit only catches a hang (a TCG guest beside a busy host is
        // slow); sdid's log says why it did not serve.
        let log_path = session.dir.path().join("sdid.log");
        sdi_tests::wait::wait_for_or(
            "sdid serving D-Bus",
            Duration::from_secs(180),
            || {
                if let Ok(Some(status)) = d._child.0.try_wait() {
                    panic!(
                        "sdid exited ({status}) before serving D-Bus; its log:\n{}",
                        std::fs::read_to_string(&log_path).unwrap_or_default()
                    );
                }
                d.ctl(&["get", "mode"]).status.success().then_some(())
            },
            || std::fs::read_to_string(&log_path).unwrap_or_default(),
        );
        sdi_tests::wait::wait_for("the sdi-camera node", Duration::from_secs(60), || {
            session.node("sdi-camera")
        });
        d
    }

    fn ctl(&self, args: &[&str]) -> std::process::Output {
        sdi_tests::dbus::sdictl(&self.address, args)
    }

    /// `sdictl set-mode`, then the mean colour of the whole 640x480 view
    /// frame: the snapshot's mean over the picture rows, black bars elsewhere.
    fn set_mode_expect(&self, mode: &str, dir: &Path) -> [f64; 3] {
        clients::set_mode_view_mean(
            |args| self.ctl(args),
            mode,
            &dir.join("snap.png"),
            PMD.width,
            PMD.height,
        )
    }
}

fn frame_like(v: &Value, expected: [f64; 3]) -> bool {
    view_frame_like(v, expected, TOLERANCE)
}

fn in_vm_checks() {
    if let Some(why) = pipewire::missing_tools().or_else(CameraPortal::missing) {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_VM",
            format_args!("the PipeWire camera test needs {why}"),
        );
        return;
    }
    let session = Session::start();
    let sdid = Sdid::start(&session);
    let _portal = CameraPortal::start(&session);
    let dir = session.dir.path().join("browser");
    std::fs::create_dir_all(&dir).expect("mkdir");
    let expected = sdid.set_mode_expect("raw", &dir);

    let server = PageServer::start();
    let browser = Browser::chromium_pipewire(&server.url, &dir, &session);
    // Chromium under TCG took 75-89 s from its start to its first frame of
    // the loopback camera (docs/loopback.md), more on a loaded host; the
    // bound counts from the page's load, after the browser's own start.
    let first = server.first_view_frame("chromium", Duration::from_secs(480), || {
        format!(
            "{}\n{}\nportal log:\n{}",
            browser.log_lines("video_capture"),
            browser.log_tail(),
            std::fs::read_to_string(session.dir.path().join("portal.log")).unwrap_or_default()
        )
    });
    eprintln!(
        "chromium (PipeWire camera): time to first frame {:.1} s (browser start to the page's first canvas frame)",
        browser.started.elapsed().as_secs_f64()
    );
    server.assert_opened_view("chromium", "SDI camera (raw)", &first);

    let (i, v) = server.wait_for(
        &format!("chromium: a raw-mode frame near {expected:.1?}"),
        0,
        Duration::from_secs(60),
        |v| frame_like(v, expected),
    );
    eprintln!(
        "chromium: raw frame mean {:.1?} (expected {expected:.1?})",
        stats_rgb(&v, "mean")
    );
    let top = &v["stats"]["top"];
    assert!(
        top.as_array()
            .is_some_and(|t| t.iter().all(|c| c.as_f64().unwrap_or(255.0) < TOLERANCE)),
        "letterbox bar not black: {top}"
    );

    let expected2 = sdid.set_mode_expect("separation", &dir);
    assert!(
        off_by(expected, expected2) > 2.0 * TOLERANCE,
        "modes too alike: {expected:?} {expected2:?}"
    );
    let t_switch = Instant::now();
    let (_, v) = server.wait_for(
        &format!("chromium: a separation frame near {expected2:.1?}"),
        i + 1,
        Duration::from_secs(60),
        |v| frame_like(v, expected2),
    );
    eprintln!(
        "chromium: set-mode separation seen after {:.1} s: mean {:.1?} (expected {expected2:.1?})",
        t_switch.elapsed().as_secs_f64(),
        stats_rgb(&v, "mean")
    );

    // sdid restarts: the camera process keeps the node, so the page's track
    // survives (no `ended`, no reopening) and shows the new sdid's frames.
    let frames_before = frames_of(&v);
    let opened_before = v["opened"].as_u64().unwrap_or(0);
    let t_restart = Instant::now();
    drop(sdid);
    let sdid = Sdid::start(&session);
    let expected3 = sdid.set_mode_expect("raw", &dir);
    let (_, v) = server.wait_for(
        &format!("chromium: raw frames near {expected3:.1?} after sdid restarted"),
        i + 1,
        Duration::from_secs(120),
        |v| frame_like(v, expected3) && frames_of(v) > frames_before,
    );
    let ended = server.of_kind("ended").len();
    eprintln!(
        "chromium: frames again {:.1} s after the restart began (ended events: {ended}, opens: {} before, {} after)",
        t_restart.elapsed().as_secs_f64(),
        opened_before,
        v["opened"]
    );
    assert_eq!(ended, 0, "the track ended across the restart");
    assert_eq!(
        v["opened"].as_u64().unwrap_or(0),
        opened_before,
        "the page had to reopen the camera across the restart"
    );

    // Issue 32: with the module loaded, sdid (--sink auto) feeds the
    // loopback nodes and this camera from the same frames: the page keeps
    // reading, ffmpeg reads the loopback node, a mode switch reaches both.
    let frames_before = frames_of(&v);
    drop(sdid);
    clients::load_module(VIEW_NR, DATA_NR);
    let t_auto = Instant::now();
    let sdid = Sdid::start_auto(&session);
    let device = stdout_of(&sdid.ctl(&["get", "device"]));
    assert!(
        device.contains(&format!("/dev/video{VIEW_NR}")) && device.contains("sdi-camera"),
        "both sinks: {device}"
    );
    let expected4 = sdid.set_mode_expect("depth-edge", &dir);
    let (_, v) = server.wait_for(
        &format!("chromium: depth-edge frames near {expected4:.1?} with the module loaded"),
        i + 1,
        Duration::from_secs(120),
        |v| frame_like(v, expected4) && frames_of(v) > frames_before,
    );
    eprintln!(
        "chromium, module loaded: depth-edge frame {:.1} s after sdid --sink auto started: mean {:.1?} (expected {expected4:.1?})",
        t_auto.elapsed().as_secs_f64(),
        stats_rgb(&v, "mean")
    );
    let seen = capture::last_frame_mean_rgb(Path::new(&format!("/dev/video{VIEW_NR}")), 640, 480);
    eprintln!(
        "ffmpeg on the loopback node, depth-edge: mean {seen:.1?} (expected {expected4:.1?})"
    );
    assert!(
        off_by(seen, expected4) < TOLERANCE,
        "loopback node {seen:?}, expected {expected4:?}"
    );
    drop(browser);
    drop(sdid);
    loopback::unload_module().expect("rmmod");
}

#[test]
fn vm_chromium_reads_the_pipewire_camera_through_the_portal() {
    if crate::GUEST.on_host() {
        return;
    }
    in_vm_checks();
}
