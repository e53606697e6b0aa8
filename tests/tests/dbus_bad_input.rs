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
    let conn = zbus::connection::Builder::address(bus.address.as_str())
        .unwrap()
        .build()
        .await
        .unwrap();
    let proxy = zbus::Proxy::new(
        &conn,
        "org.sdi.Daemon",
        "/org/sdi/Camera0",
        "org.sdi.Camera1",
    )
    .await
    .unwrap();
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
