//! sdid's start-up as a library function: `sdi_daemon::startup::serve` in
//! this process serves the camera on a private bus, refuses to start a
//! second time on the same bus with a typed error, and returns cleanly
//! (releasing the bus name) when its stop future completes.

use std::time::{Duration, Instant};

use sdi_config::{BackendKind, Config, SinkKind};
use sdi_core::mode::ModeId;
use sdi_daemon::bus::BusChoice;
use sdi_daemon::startup::{serve, StartError, StartOptions};
use sdi_tests::dbus::Bus;
use sdi_tests::require_dbus;

/// The simulator at 30 Hz into a y4m FIFO nobody reads, on `bus`.
fn options(bus: &Bus, dir: &std::path::Path, fifo: &str) -> StartOptions {
    let mut config = Config {
        backend: BackendKind::Sim,
        mode: ModeId::DepthEdge,
        frame_rate_hz: Some(30.0),
        exposure_us: Some(2000.0),
        ..Config::default()
    };
    config.output.sink = SinkKind::Y4m;
    config.output.y4m_path = dir.join(fifo).display().to_string();
    config.validate().expect("a valid configuration");
    StartOptions {
        config,
        bus: BusChoice::Address(bus.address.clone()),
        state_dir: Some(dir.to_owned()),
        mode_given: true,
    }
}

#[test]
fn serve_runs_in_process_and_stops_on_its_stop_future() {
    require_dbus!();
    let bus = Bus::start();
    let dir = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let first = serve(options(&bus, dir.path(), "view.y4m"), async {
            let _ = stop_rx.await;
            "test finished"
        });
        let client = async {
            let conn = zbus::connection::Builder::address(bus.address.as_str())
                .unwrap()
                .build()
                .await
                .unwrap();
            // Once sdid owns its name; uncached, so each read asks sdid.
            let dbus = zbus::fdo::DBusProxy::new(&conn).await.unwrap();
            let start = Instant::now();
            while !dbus
                .name_has_owner(sdi_api::BUS_NAME.try_into().unwrap())
                .await
                .unwrap()
            {
                assert!(
                    start.elapsed() < Duration::from_secs(30),
                    "sdid did not come up"
                );
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            let cam = sdi_api::Camera1Proxy::builder(&conn)
                .cache_properties(zbus::proxy::CacheProperties::No)
                .build()
                .await
                .unwrap();
            let mode = cam.mode().await.unwrap();
            assert_eq!(mode, ModeId::DepthEdge.name());
            assert_eq!(cam.backend().await.unwrap(), "sim");
            // Frames flow through the frame loop into the Stats property.
            while cam.stats().await.unwrap().frames == 0 {
                assert!(start.elapsed() < Duration::from_secs(30), "no frames");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            // A second sdid on the same bus: a typed error, the first serves on.
            let second = serve(
                options(&bus, dir.path(), "second.y4m"),
                std::future::pending(),
            );
            let second = second.await;
            assert!(
                matches!(second, Err(StartError::NameTaken)),
                "a second sdid must be refused the bus name: {second:?}"
            );
            assert_eq!(cam.mode().await.unwrap(), ModeId::DepthEdge.name());
            stop_tx.send(()).unwrap();
            conn
        };
        let (served, conn) = tokio::join!(
            async {
                tokio::time::timeout(Duration::from_secs(90), first)
                    .await
                    .expect("serve returned after its stop future")
            },
            client
        );
        served.expect("serve ended without error");
        let dbus = zbus::fdo::DBusProxy::new(&conn).await.unwrap();
        let owned = dbus
            .name_has_owner(sdi_api::BUS_NAME.try_into().unwrap())
            .await
            .unwrap();
        assert!(!owned, "the bus name is released at shutdown");
    });
}
