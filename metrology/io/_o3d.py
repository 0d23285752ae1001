"""The one place metro imports Open3D.

Open3D's Linux wheel links against ``libusb-1.0.so.0`` and fails at import on a machine
without that system library. The ``libusb-package`` wheel ships the library; we load it
with ``RTLD_GLOBAL`` before Open3D is imported, so the dynamic loader finds it already
resident and no system package is needed. Every other module calls :func:`open3d`.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys


@functools.lru_cache(maxsize=1)
def preload_libusb() -> str | None:
    """Load the libusb shipped by ``libusb-package`` into the process, globally.

    Returns the path loaded, or ``None`` where no preload is needed (not Linux) or the
    wheel is absent (then Open3D's import falls back to the system library, if any).
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        import libusb_package
    except ImportError:
        return None
    path = libusb_package.get_library_path()
    if path is None:
        return None
    path = os.fspath(path)
    ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
    return path


@functools.lru_cache(maxsize=1)
def open3d():
    """Return the ``open3d`` module, imported after libusb has been preloaded."""
    preload_libusb()
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d
