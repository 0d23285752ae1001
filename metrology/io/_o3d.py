"""The one place metro imports Open3D.

Open3D's Linux wheel links against ``libusb-1.0.so.0`` and fails at import on a machine
without that system library. The ``libusb-package`` wheel ships the library; we load it
with ``RTLD_GLOBAL`` before Open3D is imported, so the dynamic loader finds it already
resident and no system package is needed. Every other module calls :func:`open3d`.

Open3D's ``visualization`` package imports Plotly and Dash at its own import (for
``draw_plotly``, which metro never calls): about half of Open3D's import time (0.5 s CPU of
0.8 s on this machine, 40 MB). :func:`open3d` puts a stand-in for that one module first, whose
functions import the real one when called. Open3D 0.18 (the lowest version metro allows) also loads its
``ml.datasets`` at import, which loads scikit-learn (its SemanticKITTI reader's KD-tree): 1.4 s CPU of
2.4 s; that module gets a stand-in too, loading the real one at its first attribute asked.
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import os
import sys
import types

#: Open3D's module that imports Plotly and Dash, and the names its package takes from it
_PLOTLY_MODULE = "open3d.visualization.draw_plotly"
_PLOTLY_NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")
#: Open3D-ML's datasets (scikit-learn at import in Open3D 0.18), which metro never uses
_ML_DATASETS = "open3d.ml.datasets"


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
    if _PLOTLY_MODULE not in sys.modules:
        sys.modules[_PLOTLY_MODULE] = _lazy_plotly()
    if _ML_DATASETS not in sys.modules:
        sys.modules[_ML_DATASETS] = _lazy_module(_ML_DATASETS)
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def _lazy_plotly() -> types.ModuleType:
    """A stand-in for :data:`_PLOTLY_MODULE`: each of :data:`_PLOTLY_NAMES` loads the real module
    (Plotly, Dash) at its first call and calls the real function."""
    stub = types.ModuleType(_PLOTLY_MODULE, "metro's lazy stand-in: the real module loads at the first call")

    def real():
        if sys.modules.get(_PLOTLY_MODULE) is stub:
            del sys.modules[_PLOTLY_MODULE]
        return importlib.import_module(_PLOTLY_MODULE)

    def forward(name):
        def call(*args, **kwargs):
            return getattr(real(), name)(*args, **kwargs)

        call.__name__ = name
        return call

    for name in _PLOTLY_NAMES:
        setattr(stub, name, forward(name))
    return stub


def _lazy_module(name: str) -> types.ModuleType:
    """A stand-in for the module ``name``: the first attribute asked of it loads the real module
    (which then replaces it in ``sys.modules`` and in its package) and is taken from that."""
    stub = types.ModuleType(name, "metro's lazy stand-in: the real module loads at the first attribute asked")

    def __getattr__(attr):
        if attr.startswith("__"):
            raise AttributeError(attr)
        if sys.modules.get(name) is stub:
            del sys.modules[name]
        return getattr(importlib.import_module(name), attr)

    stub.__getattr__ = __getattr__
    return stub
