//! `StreamFrames` slots (issue 43, defects 3 and 9): a slot belongs to the
//! caller's bus connection and is freed when it leaves the bus; one
//! connection holds at most two of the four; a descriptor sdid could read
//! from itself (a FIFO opened read-write, both ends of one socket pair)
//! holds none; and a refused descriptor is named for what it is.

use std::os::fd::{AsFd, OwnedFd};
use std::os::unix::net::UnixStream;
use std::time::Duration;

use sdi_api::{Camera1Proxy, SdiError};
use sdi_tests::dbus::{read_write_fifo, runtime, until_ok, Daemon};
use sdi_tests::require_dbus;
use zbus::zvariant::Fd;

use crate::support::camera;

/// How long a peer's slots may stay taken after it left the bus: sdid frees
/// them on `NameOwnerChanged` (at once); the rest is room for a loaded machine.
const FREED_WITHIN: Duration = Duration::from_secs(2);

/// Passes the writing end of a new socket pair; returns the reading end
/// (held, never read: the stream cannot end by itself).
async fn open_stream(cam: &Camera1Proxy<'_>) -> Result<UnixStream, SdiError> {
    let (ours, theirs) = UnixStream::pair().unwrap();
    cam.stream_frames(Fd::from(&theirs)).await.map(|()| ours)
}

/// Tries to open a stream until it is accepted or `within` has passed.
async fn opens_within(cam: &Camera1Proxy<'_>, within: Duration) -> Result<UnixStream, String> {
    let (stream, _) = until_ok(within, || open_stream(cam)).await?;
    Ok(stream)
}

fn busy(r: &Result<UnixStream, SdiError>) -> bool {
    matches!(r, Err(SdiError::Busy(_)))
}

#[test]
fn a_peer_holds_at_most_two_slots_and_frees_them_when_it_leaves() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    runtime().block_on(async {
        let (a, cam_a) = camera(&bus).await;
        let mut held_a = vec![
            open_stream(&cam_a).await.unwrap(),
            open_stream(&cam_a).await.unwrap(),
        ];
        let third = open_stream(&cam_a).await;
        assert!(busy(&third), "a third stream of one peer: {third:?}");

        let (_, cam_b) = camera(&bus).await;
        let _held_b = [
            open_stream(&cam_b).await.unwrap(),
            open_stream(&cam_b).await.unwrap(),
        ];
        let (_, cam_c) = camera(&bus).await;
        let full = open_stream(&cam_c).await;
        assert!(busy(&full), "a fifth stream: {full:?}");

        // A leaves the bus; its readers stay open here (nobody reads them,
        // as when the read side sits with a process that is not the caller).
        drop(cam_a);
        a.close().await.unwrap();
        let _c = opens_within(&cam_c, FREED_WITHIN)
            .await
            .unwrap_or_else(|e| panic!("A left the bus, its slots stayed taken: {e}"));
        // ... and sdid closed its ends: each reader reaches end of file.
        for r in &mut held_a {
            r.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            let mut buf = vec![0u8; 1 << 16];
            loop {
                match std::io::Read::read(r, &mut buf) {
                    Ok(0) => break,
                    Ok(_) => {}
                    Err(e) => panic!("sdid kept writing a stream of a peer gone: {e}"),
                }
            }
        }
    });
}

#[test]
fn a_descriptor_sdid_could_read_itself_holds_no_slot() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    let dir = tempfile::tempdir().unwrap();
    runtime().block_on(async {
        let (a, cam_a) = camera(&bus).await;
        // A FIFO opened read-write: sdid would hold its read side.
        let rw = read_write_fifo(&dir.path().join("fifo"));
        let r = cam_a.stream_frames(Fd::from(&rw)).await;
        assert!(
            matches!(r, Err(SdiError::InvalidFd(_))),
            "FIFO opened read-write: {r:?}"
        );
        // Both ends of one socket pair: nobody but sdid could read either.
        let (x, y) = UnixStream::pair().unwrap();
        for end in [&x, &y] {
            // Refused or accepted: either way it must not keep a slot.
            let _ = cam_a.stream_frames(Fd::from(end.as_fd())).await;
        }
        drop((x, y));
        // A stays connected; B takes two slots, C must still find one.
        let (_, cam_b) = camera(&bus).await;
        let _held_b = [
            open_stream(&cam_b).await.unwrap(),
            open_stream(&cam_b).await.unwrap(),
        ];
        let (_, cam_c) = camera(&bus).await;
        let _c = opens_within(&cam_c, FREED_WITHIN)
            .await
            .unwrap_or_else(|e| panic!("streams sdid feeds itself hold slots: {e}"));
        drop(a);
    });
}

/// Issue 43 (9): a regular file or a memfd is named as what it is, and the
/// message says what is expected.
#[test]
fn a_refused_stream_descriptor_is_named_for_what_it_is() {
    require_dbus!();
    let (bus, _d) = Daemon::start_on_new_bus(&[]);
    let dir = tempfile::tempdir().unwrap();
    runtime().block_on(async {
        let (_conn, cam) = camera(&bus).await;
        let file = std::fs::File::create(dir.path().join("f")).unwrap();
        let memfd: OwnedFd =
            nix::sys::memfd::memfd_create(c"sdi-test", nix::sys::memfd::MemFdCreateFlag::empty())
                .unwrap();
        for (what, fd) in [("file", file.as_fd()), ("memfd", memfd.as_fd())] {
            let msg = match cam.stream_frames(Fd::from(fd)).await {
                Err(SdiError::InvalidFd(m)) => m,
                other => panic!("{what}: {other:?}"),
            };
            assert!(!msg.contains("not a regular file"), "{what}: {msg}");
            assert!(msg.contains("is a regular file"), "{what}: {msg}");
            assert!(
                msg.contains("pipe") && msg.contains("socket"),
                "{what}: {msg}"
            );
        }
    });
}
