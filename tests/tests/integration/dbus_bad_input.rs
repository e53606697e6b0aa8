//! Bad input gets typed errors and meaningful exit codes; a flood of calls
//! leaves the daemon responsive and at its frame rate (read from Stats).

use std::time::Duration;

use sdi_tests::dbus::{stats, Bus, Daemon};
use sdi_tests::require_dbus;

fn err(out: &std::process::Output) -> (i32, String) {
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn typed_errors_and_exit_codes() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let (code, msg) = err(&d.ctl(&["set-mode", "no-such-mode"]));
    assert_eq!(code, 2, "{msg}");
    assert!(
        msg.contains("org.sdi.Error.InvalidMode") && msg.contains("depth-edge"),
        "{msg}"
    );
    let (code, msg) = err(&d.ctl(&["set", "exposure-us", "NaN"]));
    assert_eq!(code, 2, "{msg}");
    assert!(
        msg.contains("org.sdi.Error.OutOfRange") && msg.contains("allowed"),
        "{msg}"
    );
    let (code, msg) = err(&d.ctl(&["set", "frame-rate", "-5"]));
    assert_eq!(code, 2, "{msg}");
    assert!(msg.contains("org.sdi.Error.OutOfRange"), "{msg}");
    let (code, msg) = err(&d.ctl(&["set", "exposure-us", "1e300"]));
    assert!(code == 2 && msg.contains("OutOfRange"), "{msg}");
    let (code, msg) = err(&d.ctl(&["dark-frame", "0"]));
    assert!(code == 2 && msg.contains("OutOfRange"), "{msg}");
    let (code, msg) = err(&d.ctl(&["stop"]));
    assert!(code == 6 && msg.contains("NotRecording"), "{msg}");
    let (code, msg) = err(&d.ctl(&["record", "--by-path", "/proc/x.sdirec"]));
    assert!(code == 2 && msg.contains("InvalidPath"), "{msg}");
    let (code, msg) = err(&d.ctl(&["snapshot", "--by-path", "/tmp/x.jpg"]));
    assert!(code == 2 && msg.contains("InvalidPath"), "{msg}");
    // Unreachable daemon: exit 3.
    let other = Bus::start();
    let out = sdi_tests::dbus::sdictl(&other.address, &["status"]);
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(d.ctl(&["get", "mode"]).status.code(), Some(0));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn flood_of_calls_keeps_frame_rate() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let (_conn, proxy) = sdi_tests::dbus::raw_camera_proxy(&bus.address).await;
    let modes = ["raw", "depth-edge", "bogus", "bipolar-colour"];
    let mut calls = Vec::new();
    for i in 0..1000usize {
        let p = proxy.clone();
        calls.push(tokio::spawn(async move {
            // A setting change answers (sequence, timestamp_us) of its first frame.
            let r: zbus::Result<(u64, u64)> = match i % 4 {
                0 => p.call("SetMode", &(modes[i / 4 % 4],)).await,
                1 => p.call("SetExposureUs", &(f64::NAN,)).await,
                2 => p.call("SetFrameRate", &(-1.0f64,)).await,
                _ => p.call("SetColormap", &("grey",)).await,
            };
            match r {
                Ok(_) => "ok".to_owned(),
                Err(zbus::Error::MethodError(name, _, _)) => name.as_str().to_owned(),
                Err(e) => format!("other: {e}"),
            }
        }));
    }
    let mut counts = std::collections::HashMap::<String, usize>::new();
    for c in calls {
        *counts.entry(c.await.unwrap()).or_default() += 1;
    }
    assert_eq!(
        counts.get("org.sdi.Error.OutOfRange"),
        Some(&500),
        "{counts:?}"
    );
    assert_eq!(
        counts.get("org.sdi.Error.InvalidMode"),
        Some(&62),
        "{counts:?}"
    );
    assert_eq!(counts.get("ok"), Some(&438), "{counts:?}");
    // Let one stats window pass after the flood, then read the frame rate.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let s = tokio::task::spawn_blocking(move || {
        let s = stats(&d);
        (s, d)
    })
    .await
    .unwrap()
    .0;
    let fps = s["fps"].as_f64().unwrap();
    assert!(fps > 30.0 * 0.8, "frame rate dropped to {fps}: {s}");
    assert!(s["frames"].as_u64().unwrap() > 30);
}

/// One frame-rate range (`sdi_core::sensor::capture_range::FRAME_RATE_HZ`):
/// the D-Bus setter, sdid's command line and sdid.toml accept its upper end
/// and refuse just past either end (they used to differ: 0.1-240 Hz on the
/// bus, 0-10000 Hz at start).
#[test]
fn one_frame_rate_range_on_the_bus_the_command_line_and_the_file() {
    require_dbus!();
    use sdi_core::sensor::capture_range::FRAME_RATE_HZ as R;
    let (lo, hi) = (R.min, R.max);
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    // The lower end itself is not set on the bus: at 0.1 Hz the call waits
    // for a frame 10 s away. The file and the command line take it below.
    let (code, msg) = err(&d.ctl(&["set", "frame-rate", &hi.to_string()]));
    assert_eq!(code, 0, "{msg}");
    for bad in [hi + 0.5, lo / 2.0, 1000.0, 10_000.0] {
        let (code, msg) = err(&d.ctl(&["set", "frame-rate", &bad.to_string()]));
        assert!(
            code == 2
                && msg.contains("org.sdi.Error.OutOfRange")
                && msg.contains(&format!("[{lo}, {hi}]")),
            "{bad}: {msg}"
        );
    }
    let (code, msg) = err(&d.ctl(&["set", "frame-rate", "30"]));
    assert_eq!(code, 0, "{msg}");

    // sdid refuses the same values before it starts: command line and file.
    let dir = tempfile::tempdir().unwrap();
    let sdid = |args: &[&str]| {
        sdi_tests::sdid_command::SdidCommand::new()
            .bus(&bus.address)
            .sim()
            .y4m("-")
            .args(args)
            .log("error")
            .command()
            .stdout(std::process::Stdio::null())
            .output()
            .unwrap()
    };
    for bad in [hi + 0.5, lo / 2.0, 1000.0, 10_000.0] {
        let (code, msg) = err(&sdid(&["--frame-rate-hz", &bad.to_string()]));
        assert!(
            code != 0 && msg.contains("frame_rate_hz") && msg.contains(&format!("[{lo}, {hi}]")),
            "--frame-rate-hz {bad}: {code} {msg}"
        );
        let file = dir.path().join("sdid.toml");
        std::fs::write(&file, format!("frame_rate_hz = {bad:?}\n")).unwrap();
        let (code, msg) = err(&sdid(&["--config", file.to_str().unwrap()]));
        assert!(
            code != 0 && msg.contains("frame_rate_hz") && msg.contains(&format!("[{lo}, {hi}]")),
            "frame_rate_hz = {bad}: {code} {msg}"
        );
    }
}
