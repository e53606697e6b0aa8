"""sdid's difference camera and the offline science of SDI, from Python.

Live: ``sdi.Camera()`` talks to sdid over D-Bus (``org.sdi.Camera1``);
offline: ``sdi.read_recording``, ``sdi.simulate`` and ``sdi.separate`` run
the same code as ``sdictl``. Everything is implemented in Rust (``sdi._sdi``)
on the workspace's own crates; see docs/python.md.
"""

from . import _sdi
from ._sdi import *  # noqa: F401,F403
from ._sdi import __version__  # noqa: F401

# The extension's own list (PyO3 adds each name it registers), less the
# version; the stub (`__init__.pyi`) spells it out for type checkers.
__all__ = [name for name in _sdi.__all__ if name != "__version__"]
