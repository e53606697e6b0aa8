//! sdid on a private dbus-daemon, driven by sdictl: mode round trip, change
//! signals, snapshots, introspection.

use std::process::{Command, Stdio};
use std::time::Duration;

use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::process::stdout_of;
use sdi_tests::require_dbus;
use sdi_tests::skip::have;

#[test]
fn set_mode_round_trip_and_signals() {
    require_dbus!();
    if !have("gdbus", "libglib2.0-bin", "watching the signals") {
        return;
    }
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let mut monitor = Command::new("gdbus")
        .args([
            "monitor",
            "--address",
            &bus.address,
            "--dest",
            "org.sdi.Daemon",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("gdbus monitor");
    std::thread::sleep(Duration::from_millis(500));
    stdout_of(&d.ctl(&["set-mode", "depth-edge"]));
    assert_eq!(stdout_of(&d.ctl(&["get", "mode"])).trim(), "depth-edge");
    let setup = stdout_of(&d.ctl(&["get", "setup"]));
    assert!(setup.contains("left of the lens"), "{setup}");
    stdout_of(&d.ctl(&["set", "exposure-us", "1500"]));
    assert_eq!(stdout_of(&d.ctl(&["get", "exposure-us"])).trim(), "1500.0");
    std::thread::sleep(Duration::from_millis(1500));
    let _ = monitor.kill();
    let out = monitor.wait_with_output().expect("monitor output");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("PropertiesChanged"), "{text}");
    assert!(text.contains("'Mode': <'depth-edge'>"), "{text}");
    assert!(text.contains("'ExposureUs': <1500.0>"), "{text}");
    assert!(text.contains("'Stats'"), "{text}");
}

#[test]
fn snapshot_files_are_correct() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &["--mode", "bipolar-colour"]);
    let dir = tempfile::tempdir().unwrap();
    let npy = dir.path().join("snap.npy");
    let png = dir.path().join("snap.png");
    stdout_of(&d.ctl(&["snapshot", npy.to_str().unwrap()]));
    stdout_of(&d.ctl(&["snapshot", png.to_str().unwrap()]));
    let (shape, data) = sdi_tests::npy_file::read_npy(&npy);
    assert_eq!(shape, [240, 320]);
    // Flat field LS1 = 2 x LS2: the difference is positive on average.
    let mean = data.iter().map(|&v| v as f64).sum::<f64>() / data.len() as f64;
    assert!(
        mean > 0.0 && data.iter().all(|v| v.is_finite()),
        "mean {mean}"
    );
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (320, 240));
    // Refuses to overwrite: sdictl itself (descriptor, the default) and the
    // daemon (--by-path).
    let again = d.ctl(&["snapshot", npy.to_str().unwrap()]);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists"));
    let again = d.ctl(&["snapshot", "--by-path", npy.to_str().unwrap()]);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("org.sdi.Error.InvalidPath"));
}

#[test]
fn introspection_matches_checked_in_xml() {
    require_dbus!();
    if !have("gdbus", "libglib2.0-bin", "the introspection check") {
        return;
    }
    let bus = Bus::start();
    let _d = Daemon::start(&bus, &[]);
    let out = Command::new("gdbus")
        .args([
            "call",
            "--address",
            &bus.address,
            "--dest",
            "org.sdi.Daemon",
            "--object-path",
            "/org/sdi/Camera0",
            "--method",
            "org.freedesktop.DBus.Introspectable.Introspect",
        ])
        .output()
        .unwrap();
    let text = stdout_of(&out);
    // gdbus prints ('<xml>',) (or ("<xml>",) when the text holds a quote)
    // with escaped newlines and quotes.
    let xml = text
        .replace("\\n", "\n")
        .replace("\\'", "'")
        .replace("\\\"", "\"");
    let served = interface_block(&xml);
    let file = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../daemon/dbus/org.sdi.Camera1.xml"
    ))
    .unwrap();
    let checked_in = interface_block(&file);
    assert_eq!(
        served, checked_in,
        "served introspection differs from daemon/dbus/org.sdi.Camera1.xml; served:\n{served}"
    );
}

/// The `<interface name="org.sdi.Camera1">` element, one trimmed line per tag.
fn interface_block(xml: &str) -> String {
    let start = xml
        .find("<interface name=\"org.sdi.Camera1\">")
        .expect("interface in xml");
    let end = start + xml[start..].find("</interface>").expect("end") + "</interface>".len();
    xml[start..end]
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("<!--"))
        .collect::<Vec<_>>()
        .join("\n")
}
