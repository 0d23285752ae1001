"""What outputs call an input file: its path, unless the caller named it otherwise; and its
SHA-256, by which reports and QIF documents name its content (:func:`sha256_file`).

The library reads inputs from paths (Open3D and trimesh need one), so a stream the CLI
reads from stdin reaches it as a temporary file. Every path that goes into an output the
library writes (a report's inputs, a layout's header, a plane's ``source``) passes through
:func:`display_name`, and the caller that made the temporary file names it for the
duration of the run with :func:`named_inputs`. A context variable, not a module global: a
name lives exactly as long as the ``with`` block that set it.
"""

from __future__ import annotations

import contextlib
import hashlib
from contextvars import ContextVar
from pathlib import Path

__all__ = ["display_name", "named_inputs", "sha256_file", "utc"]

_NAMES: ContextVar[dict] = ContextVar("metro_input_names", default={})


def _keys(path) -> set:
    p = Path(path)
    keys = {str(p)}
    try:
        keys.add(str(p.resolve()))
    except OSError:
        pass
    return keys


@contextlib.contextmanager
def named_inputs(names: dict):
    """Within the block, :func:`display_name` of each path in ``names`` (path -> name) is its name."""
    merged = dict(_NAMES.get())
    for path, name in names.items():
        for key in _keys(path):
            merged[key] = str(name)
    token = _NAMES.set(merged)
    try:
        yield
    finally:
        _NAMES.reset(token)


def display_name(path) -> str:
    """The name outputs give ``path`` (str or os.PathLike): the one set by
    :func:`named_inputs`, else the path as given."""
    if path is None:
        return None
    names = _NAMES.get()
    if not names:
        return str(path)
    for key in (str(path), *_keys(path)):
        if key in names:
            return names[key]
    return str(path)


def sha256_file(path) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def utc(t_s: float) -> str:
    """ISO 8601 UTC, to the second, of ``t_s`` seconds since 1970-01-01: how outputs and errors name a time."""
    import datetime as dt

    return dt.datetime.fromtimestamp(float(t_s), dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
