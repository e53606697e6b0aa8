//! Long jobs (issue 43, defects 4 and 5): a setting change while a job
//! holds the camera is refused with `Busy` naming the job, never answered
//! ok and dropped; a job ends when its caller leaves the bus or anyone of
//! its user calls `Cancel`; it is bounded in seconds; it reports its
//! progress in the `Job` property; a snapshot during it answers at once;
//! recordings and jobs exclude each other (a job would leave a gap in the
//! recording).
//!
//! The calls new with issue 43 (`Cancel`, `Job`) go through an untyped
//! proxy, so this file also builds (and fails) against sdid without them.

use std::time::{Duration, Instant};

use sdi_api::{Camera1Proxy, SdiError};
use sdi_tests::dbus::{runtime, until_ok, Bus, Daemon};
use sdi_tests::require_dbus;
use zbus::zvariant::{Fd, OwnedValue};

use crate::support::camera;

/// Frames per step of the calibration these tests start: 300 dark frames
/// and 5 x 300 photon-transfer frames, a minute at 30 Hz: it runs until
/// the test ends it.
const LONG: u32 = 300;

/// Sends `Calibrate(frames)` on `conn` without waiting for the reply;
/// returns the call's serial number.
async fn send_calibrate(conn: &zbus::Connection, frames: u32) -> zbus::Message {
    let msg = zbus::Message::method_call("/org/sdi/Camera0", "Calibrate")
        .unwrap()
        .destination("org.sdi.Daemon")
        .unwrap()
        .interface("org.sdi.Camera1")
        .unwrap()
        .build(&(frames,))
        .unwrap();
    conn.send(&msg).await.unwrap();
    msg
}

/// An untyped proxy of the camera that reads properties from sdid each time.
async fn uncached(conn: &zbus::Connection) -> zbus::Proxy<'static> {
    zbus::proxy::Builder::new(conn)
        .destination("org.sdi.Daemon")
        .unwrap()
        .path("/org/sdi/Camera0")
        .unwrap()
        .interface("org.sdi.Camera1")
        .unwrap()
        .cache_properties(zbus::proxy::CacheProperties::No)
        .build()
        .await
        .unwrap()
}

/// Waits until a job holds the camera (its `Job` property names it).
async fn wait_for_job(cam: &Camera1Proxy<'_>) {
    let raw = uncached(cam.inner().connection()).await;
    let t0 = Instant::now();
    loop {
        let job: OwnedValue = raw
            .get_property("Job")
            .await
            .unwrap_or_else(|e| panic!("the Job property: {e}"));
        let d: std::collections::HashMap<String, OwnedValue> = job.try_into().unwrap();
        if String::try_from(d["name"].try_clone().unwrap()).unwrap() != "" {
            return;
        }
        assert!(t0.elapsed() < Duration::from_secs(20), "no job started");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Waits until no job holds the camera (a 1-frame dark capture goes
/// through); how long that took.
async fn wait_for_no_job(cam: &Camera1Proxy<'_>, within: Duration) -> Result<Duration, String> {
    let (_, took) = until_ok(within, || cam.capture_dark_frame(1)).await?;
    Ok(took)
}

/// Starts a long calibration on a connection of its own and waits until
/// it holds the camera; that connection, and the camera on another.
async fn job_of_another(bus: &Bus) -> (zbus::Connection, Camera1Proxy<'static>) {
    let a = bus.connect().await;
    send_calibrate(&a, LONG).await;
    let (_, cam) = camera(bus).await;
    wait_for_job(&cam).await;
    (a, cam)
}

#[test]
fn a_setting_change_during_a_job_is_refused_naming_the_job() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    runtime().block_on(async {
        let (a, cam) = job_of_another(&bus).await;
        let before = cam.exposure_us().await.unwrap();
        let r = cam.set_exposure_us(1000.0).await;
        match &r {
            Err(SdiError::Busy(m)) => assert!(m.contains("calibration"), "{m}"),
            other => panic!("SetExposureUs(1000) during Calibrate: {other:?}"),
        }
        assert_eq!(cam.exposure_us().await.unwrap(), before);
        let r = cam.set_frame_rate(20.0).await;
        assert!(matches!(r, Err(SdiError::Busy(_))), "SetFrameRate: {r:?}");
        assert_eq!(cam.frame_rate().await.unwrap(), 30.0);
        // Once the job is gone, the change is taken and kept.
        a.close().await.unwrap();
        wait_for_no_job(&cam, Duration::from_secs(10))
            .await
            .unwrap();
        cam.set_exposure_us(1000.0).await.unwrap();
        assert_eq!(cam.exposure_us().await.unwrap(), 1000.0);
    });
}

#[test]
fn a_job_ends_when_its_caller_leaves_the_bus() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    runtime().block_on(async {
        let (a, cam) = job_of_another(&bus).await;
        a.close().await.unwrap();
        // sdid cancels on NameOwnerChanged; a frame or two to put the
        // settings back; the rest is room for a loaded machine.
        let took = wait_for_no_job(&cam, Duration::from_secs(3))
            .await
            .unwrap_or_else(|e| panic!("the caller left, its calibration ran on: {e}"));
        eprintln!("job ended {took:?} after its caller left");
        assert_eq!(cam.exposure_us().await.unwrap(), 2000.0);
    });
}

#[test]
fn cancel_ends_a_job_and_progress_is_reported() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    runtime().block_on(async {
        let (_a, cam_a) = camera(&bus).await;
        let (b, cam_b) = camera(&bus).await;
        let raw_b = uncached(&b).await;
        let job = tokio::spawn(async move { cam_a.calibrate(LONG).await });
        wait_for_job(&cam_b).await;

        // Progress: the Job property names the job and counts its frames.
        let progress = |v: OwnedValue| -> (String, u32, u32) {
            let d: std::collections::HashMap<String, OwnedValue> = v.try_into().unwrap();
            let s = |k: &str| String::try_from(d[k].try_clone().unwrap()).unwrap();
            let u = |k: &str| u32::try_from(d[k].try_clone().unwrap()).unwrap();
            (s("name"), u("frames_done"), u("frames_total"))
        };
        let read = || async {
            let v: OwnedValue = raw_b
                .get_property("Job")
                .await
                .unwrap_or_else(|e| panic!("the Job property: {e}"));
            progress(v)
        };
        let (name, done0, total) = read().await;
        assert_eq!(name, "calibration");
        assert_eq!(total, LONG * 6, "dark frames and five levels");
        tokio::time::sleep(Duration::from_millis(1500)).await;
        let (_, done1, _) = read().await;
        assert!(done1 > done0, "no progress: {done0} then {done1}");

        // A snapshot during the job answers at once (Busy, naming the job).
        let dir = tempfile::tempdir().unwrap();
        let f = std::fs::File::create(dir.path().join("s.png")).unwrap();
        let t0 = Instant::now();
        let snap = tokio::time::timeout(
            Duration::from_secs(3),
            cam_b.snapshot_to_fd(Fd::from(&f), "png"),
        )
        .await;
        assert!(
            matches!(&snap, Ok(Err(SdiError::Busy(m))) if m.contains("calibration")),
            "a snapshot during a job, after {:?}: {snap:?}",
            t0.elapsed()
        );
        // A recording would have a gap: refused while the job runs.
        let rec = std::fs::File::create(dir.path().join("r.sdirec")).unwrap();
        let r = cam_b.start_recording_to_fd(Fd::from(&rec), "r").await;
        assert!(matches!(r, Err(SdiError::Busy(_))), "recording: {r:?}");

        // Cancel: the caller's call ends with Cancelled, the camera is free.
        let reply = raw_b.call_method("Cancel", &()).await;
        let cancelled: String = reply
            .unwrap_or_else(|e| panic!("Cancel: {e}"))
            .body()
            .deserialize()
            .unwrap();
        assert_eq!(cancelled, "calibration");
        let r = tokio::time::timeout(Duration::from_secs(3), job)
            .await
            .expect("the cancelled call returns")
            .unwrap();
        let err = r
            .as_ref()
            .err()
            .map(ToString::to_string)
            .unwrap_or_default();
        assert!(
            err.starts_with("org.sdi.Error.Cancelled"),
            "the cancelled call: {r:?}"
        );
        let (name, _, _) = read().await;
        assert_eq!(name, "", "no job after the cancel");
        wait_for_no_job(&cam_b, Duration::from_secs(3))
            .await
            .unwrap();
        // Nothing to cancel: "" (not an error).
        let reply = raw_b.call_method("Cancel", &()).await.unwrap();
        assert_eq!(reply.body().deserialize::<String>().unwrap(), "");
    });
}

#[test]
fn a_job_is_bounded_in_seconds_and_excludes_a_recording() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    let dir = tempfile::tempdir().unwrap();
    runtime().block_on(async {
        let (_conn, cam) = camera(&bus).await;
        // 60,000 frames at 30 Hz: over half an hour.
        let r = tokio::time::timeout(Duration::from_secs(10), cam.calibrate(10_000)).await;
        match &r {
            Ok(Err(SdiError::OutOfRange(m))) => assert!(m.contains(" s"), "{m}"),
            other => panic!("Calibrate(10000) at 30 Hz was not refused: {other:?}"),
        }
        // A job while recording is refused (the recording would have a gap).
        let rec = std::fs::File::create(dir.path().join("r.sdirec")).unwrap();
        cam.start_recording_to_fd(Fd::from(&rec), "r")
            .await
            .unwrap();
        let r = tokio::time::timeout(Duration::from_secs(10), cam.capture_dark_frame(4)).await;
        assert!(
            matches!(&r, Ok(Err(SdiError::Busy(m))) if m.contains("recording")),
            "a dark frame while recording: {r:?}"
        );
        cam.stop_recording().await.unwrap();
        cam.capture_dark_frame(4).await.unwrap();
    });
}

/// The stall of stop 50: a job's watch of its caller's departure sent on
/// the connection from inside `job_step`'s `select!`; polled once, it
/// queued for zbus's write lock, and the progress signal the branch body
/// then sent queued behind it. The lock went to the watch, which was never
/// polled again: every later send of sdid waited forever (no reply, not
/// even to `Peer.Ping`). Here the bus is stopped so that a large signal
/// holds the write lock, the watch is polled once, and a send awaited
/// beside it must go through once the bus runs again.
#[test]
fn a_departure_watch_left_unpolled_holds_up_no_send() {
    use nix::sys::signal::Signal;
    use sdi_daemon::dbus::peers::Departure;
    require_dbus!();
    let bus = Bus::start();
    runtime().block_on(async {
        let conn = bus.connect().await;
        let caller = bus.connect().await;
        let name = caller.unique_name().unwrap().to_owned();
        let emit = |c: zbus::Connection, body: Vec<u8>| async move {
            c.emit_signal(None::<()>, "/", "org.sdi.Test", "Sent", &body)
                .await
        };
        // A stopped bus reads nothing: the large signal fills the socket
        // and its send holds the write lock.
        sdi_tests::process::signal(bus.pid(), Signal::SIGSTOP);
        let big = tokio::spawn(emit(conn.clone(), vec![0; 8 << 20]));
        tokio::time::sleep(Duration::from_millis(200)).await;
        let mut departure = Departure::watch(conn.clone(), name);
        // Polled once, as `select!` polls its branches ...
        tokio::select! {
            biased;
            () = &mut departure => panic!("the caller has not left"),
            () = tokio::time::sleep(Duration::from_millis(200)) => {}
        }
        let pid = bus.pid();
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(300));
            sdi_tests::process::signal(pid, Signal::SIGCONT);
        });
        // ... then a branch body sends while the watch sits unpolled.
        let t0 = Instant::now();
        tokio::time::timeout(Duration::from_secs(20), emit(conn.clone(), vec![1]))
            .await
            .unwrap_or_else(|_| panic!("a send stalled behind the departure watch"))
            .unwrap();
        eprintln!(
            "the send went through {:?} after the bus was stopped",
            t0.elapsed()
        );
        big.await.unwrap().unwrap();
        // And the watch still sees the caller leave.
        caller.close().await.unwrap();
        tokio::time::timeout(Duration::from_secs(10), departure)
            .await
            .expect("the caller's departure was missed");
    });
}
