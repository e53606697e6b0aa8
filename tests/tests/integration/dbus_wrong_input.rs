//! Calls the typed proxy cannot make wrong: arguments of the wrong D-Bus
//! type get one documented error and leave the daemon serving; a path with
//! a trailing slash is the same `InvalidPath` for both path methods.

use sdi_tests::dbus::{raw_camera_proxy, Bus, Daemon};
use sdi_tests::require_dbus;

/// The D-Bus error name of a failed call.
fn error_name(e: zbus::Error) -> String {
    match e {
        zbus::Error::MethodError(name, _, _) => name.to_string(),
        other => format!("not a method error: {other}"),
    }
}

/// A wrong signature is refused by zbus's object server before sdid's code
/// runs, as `org.freedesktop.zbus.Error` (docs/dbus.md, "Errors"); nothing
/// changes and the daemon goes on serving.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_signature_is_refused_and_changes_nothing() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let (_conn, proxy) = raw_camera_proxy(&d.address).await;
    let wrong: [(&str, zbus::Result<zbus::Message>); 4] = [
        ("SetMode(u)", proxy.call_method("SetMode", &(7u32,)).await),
        (
            "SetFrameRate(s)",
            proxy.call_method("SetFrameRate", &("fast",)).await,
        ),
        (
            "SetExposureUs()",
            proxy.call_method("SetExposureUs", &()).await,
        ),
        (
            "CaptureDarkFrame(uu)",
            proxy.call_method("CaptureDarkFrame", &(1u32, 2u32)).await,
        ),
    ];
    for (call, r) in wrong {
        let name = error_name(r.expect_err(call));
        eprintln!("{call} -> {name}");
        assert_eq!(name, "org.freedesktop.zbus.Error", "{call}");
    }
    let mode: String = proxy.get_property("Mode").await.unwrap();
    assert_eq!(mode, "raw");
    assert!(d.ctl(&["set-mode", "depth-edge"]).status.success());
}

#[test]
fn a_trailing_slash_is_invalid_path_for_both_path_methods() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    for args in [
        ["snapshot", "--by-path", "/tmp/new.png/"],
        ["record", "--by-path", "/tmp/new.sdirec/"],
    ] {
        let out = d.ctl(&args);
        let msg = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {msg}");
        assert!(msg.contains("org.sdi.Error.InvalidPath"), "{args:?}: {msg}");
    }
}
