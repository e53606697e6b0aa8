"""Fixtures: the programs built from the workspace, and a real sdid
(simulator backend) on a private session bus, as tests/src/dbus.rs starts
them for the Rust D-Bus tests."""

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

import sdi

REPO = Path(__file__).resolve().parents[2]


def missing(why):
    """Skips with what to install or build; fails under CI's require flag
    (`SDI_REQUIRE_PYTHON`, set by .ci/run), where everything is there."""
    if os.environ.get("SDI_REQUIRE_PYTHON"):
        pytest.fail(f"{why} (SDI_REQUIRE_PYTHON is set)")
    pytest.skip(why)


def program(name):
    """sdid or sdictl: $SDID / $SDICTL, else target/debug of the workspace."""
    path = os.environ.get(name.upper()) or str(REPO / "target" / "debug" / name)
    if not os.access(path, os.X_OK):
        missing(f"{name} is not built ({path}): cargo build -p sdi-daemon -p sdi-cli")
    return path


@pytest.fixture(scope="session")
def sdictl():
    return program("sdictl")


class Daemon:
    """sdid --session --backend sim on a private bus, stopped at the end."""

    def __init__(self, tmp, extra=(), ready_serial=None, y4m="-"):
        if shutil.which("dbus-daemon") is None:
            missing("dbus-daemon is not installed (apt-get install dbus)")
        sdid = program("sdid")
        self.bus = subprocess.Popen(
            ["dbus-daemon", "--session", "--nofork", "--nopidfile", "--print-address=1"],
            stdout=subprocess.PIPE,
            text=True,
        )
        self.address = self.bus.stdout.readline().strip()
        env = dict(os.environ, DBUS_SESSION_BUS_ADDRESS=self.address, RUST_LOG="warn")
        env.pop("INVOCATION_ID", None)
        self.env = env
        state = tmp / "state"
        state.mkdir(exist_ok=True)
        self.sdid = subprocess.Popen(
            [sdid, "--session", "--backend", "sim", "--sink", "y4m", "--y4m-path", y4m,
             "--frame-rate-hz", "30", "--exposure-us", "2000", "--state-dir", str(state),
             *extra],
            stdout=subprocess.DEVNULL,
            env=env,
        )
        deadline = time.monotonic() + 30
        while True:
            try:
                sdi.Camera(address=self.address, serial=ready_serial)
                break
            except sdi.BusError:
                if time.monotonic() > deadline or self.sdid.poll() is not None:
                    self.stop()
                    raise
                time.sleep(0.1)

    def ctl(self, sdictl, *args):
        return subprocess.run(
            [sdictl, "--bus-address", self.address, *args],
            capture_output=True, text=True, check=True,
        )

    def stop(self):
        for p in (self.sdid, self.bus):
            p.kill()
            p.wait()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("sdid"))
    yield d
    d.stop()


@pytest.fixture
def camera(daemon, monkeypatch):
    """A Camera on the session bus, which is the private bus here."""
    monkeypatch.setenv("DBUS_SESSION_BUS_ADDRESS", daemon.address)
    return sdi.Camera(bus="session")
