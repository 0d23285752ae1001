"""Atomic file writes: a file is either complete or not there."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text", "check_output_file"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_output_file(path, what: str, suffixes=None) -> Path:
    """Refuse, before any work, an output that cannot be written as one file (ValueError naming
    ``what`` and the path): a path ending in a separator (a ``Path`` would drop it and write a
    file of that name), an existing folder, a folder that does not exist, or a suffix not in
    ``suffixes`` (lower case, with the dot; None: any). Returns the path."""
    text = str(path)
    if text.endswith((os.sep,) + ((os.altsep,) if os.altsep else ())):
        raise ValueError(f"{what} {text}: ends in a separator, expected a file name (not a folder)")
    p = Path(text)
    if p.is_dir():
        raise ValueError(f"{what} {text}: is a folder, expected a file name")
    if not p.resolve().parent.is_dir():
        raise ValueError(f"{what} {text}: folder {p.parent} does not exist")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise ValueError(f"{what} {text}: must be one of {', '.join(sorted(suffixes))}")
    return p


@contextmanager
def atomic_path(path, suffix=None):
    """Yield a temporary path beside ``path``; move it onto ``path`` only on success.

    The temporary file keeps ``path``'s suffix (or ``suffix``) so that writers that pick
    a format by extension (matplotlib, Open3D, trimesh) still work.
    """
    path = Path(path)
    if path.parent and not path.parent.exists():
        raise ValueError(f"{path}: directory {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent or ".")
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual mode
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
