"""Frames per second through ``cam.frames()`` at 640x480 (simulator
backend, a private session bus), and the CPU time this process spent, beside
reading the same sdid's y4m output with numpy.

    python python/examples/stream_fps.py [SECONDS]

Needs sdid built (target/debug/sdid, or $SDID) and dbus-daemon.
"""

import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import sdi

REPO = Path(__file__).resolve().parents[2]
SDID = os.environ.get("SDID") or str(REPO / "target" / "debug" / "sdid")


def start(tmp, y4m_out):
    """dbus-daemon and sdid at 640x480, 240 Hz asked; returns (bus, sdid, address)."""
    ti = (REPO / "core" / "sensors" / "ti.toml").read_text()
    sensor = Path(tmp) / "vga.toml"
    sensor.write_text(re.sub(r"(?m)^height = \d+", "height = 480",
                             re.sub(r"(?m)^width = \d+", "width = 640", ti)))
    bus = subprocess.Popen(["dbus-daemon", "--session", "--nofork", "--nopidfile",
                            "--print-address=1"], stdout=subprocess.PIPE, text=True)
    address = bus.stdout.readline().strip()
    env = dict(os.environ, DBUS_SESSION_BUS_ADDRESS=address, RUST_LOG="warn")
    sdid = subprocess.Popen(
        [SDID, "--session", "--backend", "sim", "--sensor", str(sensor),
         "--frame-rate-hz", "240", "--sink", "y4m", "--y4m-path", "-",
         "--state-dir", str(Path(tmp) / "state")],
        stdout=y4m_out, env=env)
    for _ in range(300):
        try:
            sdi.Camera(address=address)
            break
        except sdi.BusError:
            time.sleep(0.1)
    return bus, sdid, address


def stop(*procs):
    for p in procs:
        p.kill()
        p.wait()


def through_frames(seconds):
    with tempfile.TemporaryDirectory() as tmp:
        bus, sdid, address = start(tmp, subprocess.DEVNULL)
        try:
            cam = sdi.Camera(address=address)
            n, cpu0, t0 = 0, time.process_time(), time.monotonic()
            with cam.frames() as frames:
                for f in frames:
                    n += 1
                    if time.monotonic() - t0 >= seconds:
                        break
            wall, cpu = time.monotonic() - t0, time.process_time() - cpu0
            return n / wall, cpu / wall, cam.stats["fps"], f.dn.shape, f.dropped
        finally:
            stop(sdid, bus)


def through_y4m(seconds):
    with tempfile.TemporaryDirectory() as tmp:
        bus, sdid, address = start(tmp, subprocess.PIPE)
        try:
            out = sdid.stdout
            header = out.readline().decode()
            w = int(re.search(r" W(\d+)", header).group(1))
            h = int(re.search(r" H(\d+)", header).group(1))
            n, cpu0, t0 = 0, time.process_time(), time.monotonic()
            while time.monotonic() - t0 < seconds:
                out.readline()  # FRAME
                yuv = np.frombuffer(out.read(3 * w * h), np.uint8).reshape(3, h, w)
                n += 1
            wall, cpu = time.monotonic() - t0, time.process_time() - cpu0
            return n / wall, cpu / wall, yuv.shape
        finally:
            stop(sdid, bus)


def main():
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    fps, cpu, sdid_fps, shape, dropped = through_frames(seconds)
    print(f"cam.frames(): {fps:.1f} frames/s of {shape} float32 DN + flags "
          f"(sdid's own rate {sdid_fps:.1f} fps, {dropped} dropped by the stream); "
          f"this process {100 * cpu:.1f}% of a core")
    fps, cpu, shape = through_y4m(seconds)
    print(f"y4m + numpy:  {fps:.1f} frames/s of {shape} uint8 C444; "
          f"this process {100 * cpu:.1f}% of a core")


if __name__ == "__main__":
    main()
