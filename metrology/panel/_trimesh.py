"""trimesh, imported with its STEP reader's library deferred to the first STEP read.

``import trimesh`` imports ``trimesh.exchange.cascade``, which imports ``cascadio`` (OpenCASCADE, the ``step``
extra) to register the STEP loader, a library that only a STEP read uses, paid by every ``metro measure --panel``
of an STL (0.15-0.2 s CPU of trimesh's 0.5-0.6 s on this machine, ``benchmarks/results/
measure_panel_speed_issue49_r6.md``). :func:`trimesh` puts a stand-in for ``cascadio`` first whose attributes
import the real module at their first use (as :mod:`metrology.io._o3d` does for Open3D's Plotly module; the
standard library's ``LazyLoader`` loads at the ``import`` statement itself on Python 3.11), then imports trimesh.
The loader is registered the same and a STEP is read by the same library.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types

#: the libraries trimesh imports at its own import that a mesh read without them never uses
_DEFERRED = ("cascadio",)


def trimesh():
    """Return the ``trimesh`` module, imported with :data:`_DEFERRED` loaded at their first use."""
    if "trimesh" not in sys.modules:
        for name in _DEFERRED:
            _defer(name)
    import trimesh as tm

    return tm


class _Deferred(types.ModuleType):
    """A stand-in whose first attribute not set here imports the real module (then every attribute is the real
    module's: what imported the stand-in keeps it)."""

    def __getattr__(self, attr):
        if attr.startswith("__"):
            raise AttributeError(attr)
        name = self.__name__
        if sys.modules.get(name) is self:
            del sys.modules[name]
        return getattr(importlib.import_module(name), attr)


def _defer(name: str) -> None:
    """Put a stand-in for ``name`` in ``sys.modules`` (nothing where it is imported already or not installed:
    then trimesh's own import finds it, or fails, as before)."""
    if name in sys.modules or importlib.util.find_spec(name) is None:
        return
    sys.modules[name] = _Deferred(name, "metro's stand-in: the real module loads at its first attribute")
