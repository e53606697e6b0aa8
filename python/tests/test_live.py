"""sdi.Camera against a real sdid (simulator backend) on a private bus."""

import threading
import time

import numpy as np
import pytest

import sdi


def test_settings_are_properties(camera):
    camera.mode = "depth-edge"
    assert camera.mode == "depth-edge"
    lo, hi = camera.limits["ExposureUs"]
    assert lo < 1500 < hi
    camera.exposure_us = 1500
    assert camera.exposure_us == 1500
    seq, ts = camera.set("exposure-us", 2000)
    assert seq > 0 and ts > 0
    assert camera.status()["ExposureUs"] == 2000
    assert "depth-edge" in camera.modes
    assert camera.backend == "sim"


def test_refused_setting_raises_the_typed_error_and_changes_nothing(camera):
    before = camera.status()
    with pytest.raises(sdi.OutOfRange) as e:
        camera.exposure_us = 1e9
    assert isinstance(e.value, sdi.Error)
    assert "xposure" in str(e.value) or "range" in str(e.value), str(e.value)
    with pytest.raises(sdi.InvalidMode) as e:
        camera.mode = "no-such-mode"
    assert "depth-edge" in str(e.value)  # sdid's message lists the modes
    after = camera.status()
    for key in ("Mode", "ExposureUs", "FrameRate", "ModulationHz"):
        assert after[key] == before[key], key


def test_every_sdid_error_is_an_sdi_error():
    for name in ("InvalidMode", "OutOfRange", "DeviceUnavailable", "Busy", "InvalidPath",
                 "InvalidFd", "NotRecording", "NoFrame", "RecordingStopped", "Failed",
                 "BusError", "Timeout", "StreamError"):
        assert issubclass(getattr(sdi, name), sdi.Error), name


@pytest.mark.parametrize("mode", ["depth-edge", "separation"])
def test_thirty_frames_match_sdictl_snapshot(camera, daemon, sdictl, tmp_path, mode):
    """30 frames through ``cam.frames()``, and ``sdictl snapshot`` taken
    while they stream: the snapshot is one of the streamed frames, bit for
    bit. A reader thread keeps the stream drained (the GIL is released while
    it waits), at 10 fps, so the snapshot's frame is not dropped."""
    camera.mode = mode
    camera.frame_rate = 10
    shape = (camera.height, camera.width)
    got = []
    snapped = threading.Event()
    try:
        with camera.frames() as frames:

            def read():
                for f in frames:
                    got.append(f)
                    if len(got) >= 30 and snapped.is_set():
                        return

            reader = threading.Thread(target=read)
            reader.start()
            deadline = time.monotonic() + 30
            while len(got) < 15 and time.monotonic() < deadline:
                time.sleep(0.05)
            daemon.ctl(sdictl, "snapshot", str(tmp_path / "snap.npy"))
            snapped.set()
            reader.join(30)
    finally:
        camera.frame_rate = 30
    assert len(got) >= 30
    seqs = [f.sequence for f in got]
    assert seqs == sorted(set(seqs))
    assert all(b.timestamp_us > a.timestamp_us for a, b in zip(got, got[1:]))
    for f in got:
        assert f.mode == mode
        assert f.dn.dtype == np.float32 and f.dn.shape == shape
        assert f.flags.dtype == np.uint8 and f.flags.shape == shape
        if mode == "separation":
            for plane in (f.i_plus, f.i_minus, f.i_plus_se, f.i_minus_se):
                assert plane is not None and plane.shape == shape and plane.dtype == np.float32
        else:
            assert f.i_plus is None
    snap = np.load(tmp_path / "snap.npy")
    # The separation mode's snapshot is I+ and I- (electrons), the others' the signed DN.
    if mode == "separation":
        streamed = [np.stack([f.i_plus, f.i_minus]) for f in got]
    else:
        streamed = [f.dn for f in got]
    assert snap.shape == streamed[0].shape and snap.dtype == np.float32
    same = [f.sequence for f, s in zip(got, streamed) if np.array_equal(s, snap)]
    assert len(same) == 1, (
        f"the snapshot equals {len(same)} of the streamed frames {seqs[0]}..{seqs[-1]} "
        f"(dropped by the stream: {got[-1].dropped})"
    )


def test_frame_and_timeout_say_what_sdid_reports(camera):
    f = camera.frame(timeout=5.0)
    assert f.sequence > 0
    lo, _ = camera.limits["FrameRate"]
    camera.frame_rate = max(lo, 0.5)
    try:
        timeouts = []
        for _ in range(3):
            try:
                camera.frame(timeout=0.01)
            except sdi.Timeout as e:
                timeouts.append(str(e))
        assert timeouts, "no timeout in three tries at 0.5 fps"
        assert "sdid (sim backend" in timeouts[0], timeouts[0]
    finally:
        camera.frame_rate = 30


def test_the_gil_is_released_while_waiting(camera):
    camera.frame_rate = 5
    try:
        done = threading.Event()
        count = 0

        def wait():
            with camera.frames(timeout=5.0) as frames:
                for _, _ in zip(frames, range(3)):
                    pass
            done.set()

        t = threading.Thread(target=wait)
        t.start()
        while not done.is_set():
            count += 1
            time.sleep(0)
        t.join()
        assert count > 1000
    finally:
        camera.frame_rate = 30


def test_a_recording_reads_back(camera, daemon, sdictl, tmp_path):
    camera.mode = "depth-edge"
    path = tmp_path / "r.sdirec"
    daemon.ctl(sdictl, "record", "--seconds", "1", str(path))
    rec = sdi.read_recording(path)
    assert rec.header["mode"] == "depth-edge" and rec.mode == "depth-edge"
    stack = rec.read()
    assert stack.dtype == np.float32 and stack.shape[1:] == (rec.height, rec.width)
    assert stack.shape[0] >= 10
    frames = list(rec)
    assert len(frames) == stack.shape[0]
    np.testing.assert_array_equal(frames[3].dn, stack[3])
    np.testing.assert_array_equal(rec.read(2, 5), stack[2:5])
    assert all(f.mode == "depth-edge" for f in frames)


def test_several_cameras_are_chosen_by_serial(tmp_path, sdictl):
    """`sdid --cameras 2`: sdi.cameras() lists both; Camera(serial=...)
    opens one; without a serial, a ValueError that names them."""
    from conftest import Daemon

    d = Daemon(tmp_path, extra=("--cameras", "2"), ready_serial="sim-1",
               y4m=str(tmp_path / "view.y4m"))
    try:
        assert sdi.cameras(address=d.address) == ["sim-0", "sim-1"]
        with pytest.raises(ValueError, match="sim-0, sim-1"):
            sdi.Camera(address=d.address)
        with pytest.raises(ValueError, match="sim-7"):
            sdi.Camera(address=d.address, serial="sim-7")
        second = sdi.Camera(address=d.address, serial="sim-1")
        assert second.serial == "sim-1"
        second.mode = "depth-edge"
        assert sdi.Camera(address=d.address, serial="sim-0").mode == "raw"
        assert second.mode == "depth-edge"
        assert second.frame().mode == "depth-edge"
    finally:
        d.stop()
