"""sdid's difference camera and the offline science of SDI, from Python.

Live: ``sdi.Camera()`` talks to sdid over D-Bus (``org.sdi.Camera1``);
offline: ``sdi.read_recording``, ``sdi.simulate`` and ``sdi.separate`` run
the same code as ``sdictl``. Everything is implemented in Rust (``sdi._sdi``)
on the workspace's own crates; see docs/python.md.
"""

from ._sdi import *  # noqa: F401,F403
from ._sdi import __version__  # noqa: F401

__all__ = [
    "Busy",
    "Cancelled",
    "BusError",
    "Camera",
    "DeviceUnavailable",
    "Error",
    "Failed",
    "Frame",
    "FrameStream",
    "InvalidFd",
    "InvalidMode",
    "InvalidPath",
    "NoFrame",
    "NotRecording",
    "OutOfRange",
    "RecordedFrame",
    "Recording",
    "RecordingFrames",
    "RecordingStopped",
    "Separation",
    "StreamError",
    "Timeout",
    "modes",
    "read_recording",
    "scenes",
    "separate",
    "simulate",
]
