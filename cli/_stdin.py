"""``-`` for stdin: the one input of a command that is read from stdin.

The library reads files (Open3D and trimesh need a path), so stdin is spooled to a
temporary file with the suffix of its format, removed when the command ends; messages
name it ``<stdin>`` (line numbers are those of the stream). Only one input per command
can be ``-``.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import tempfile
from pathlib import Path

from ._common import STATE, fail, note

STDIN_NAME = "<stdin>"


def sniff_suffix(data: bytes) -> str | None:
    """The file suffix a stream's first bytes show (``.ply``, ``.pcd``, ``.json``, ``.stl``,
    ``.glb``), or None when they do not tell."""
    head = data[:512].lstrip()
    if head.startswith(b"ply"):
        return ".ply"
    if head.startswith(b"# .PCD") or head.startswith(b"VERSION"):
        return ".pcd"
    if head.startswith(b"{"):
        return ".json"
    if head.startswith(b"solid"):
        return ".stl"
    if head.startswith(b"glTF"):
        return ".glb"
    return None


@contextlib.contextmanager
def stdin_files(*inputs):
    """Yield the paths of ``inputs``, the one given as ``-`` replaced by a temporary copy of stdin.

    Parameters
    ----------
    *inputs : (label, value, suffix)
        ``label`` the argument or option as the user typed it (``EXPORT``, ``--plane``);
        ``value`` its path (or None); ``suffix`` the format of a stream on stdin: a suffix
        (``".csv"``), or a callable ``suffix(data) -> str`` that fails with a message when
        the data do not tell.
    """
    for label, value, _ in inputs:
        if value is not None and str(value) != "-":
            check_input(label, value)
    dashes = [(label, suffix) for label, value, suffix in inputs if value is not None and str(value) == "-"]
    if len(dashes) > 1:
        fail(f"'-' (stdin) given to both {dashes[0][0]} and {dashes[1][0]}: only one input can be read from stdin")
    if not dashes:
        yield [value for _, value, _ in inputs]
        return
    label, suffix = dashes[0]
    data = sys.stdin.buffer.read()
    if not data:
        fail(f"{label} -: nothing on stdin")
    if callable(suffix):
        suffix = suffix(data)
    tmp = Path(tempfile.mkdtemp(prefix="metro-stdin-"))
    try:
        path = tmp / f"stdin{suffix}"
        path.write_bytes(data)
        for form in {str(path), str(path.resolve())}:
            STATE.aliases[form] = STDIN_NAME
        note(f"{label}: read {len(data)} bytes from stdin (as {suffix[1:]})")
        from metrology.io.names import named_inputs

        with named_inputs({path: STDIN_NAME}):  # what the files the library writes call it
            yield [path if value is not None and str(value) == "-" else value for _, value, _ in inputs]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


#: the suffixes an input is read by, where the suffix chooses the reader (else any name)
def _accepted(label: str):
    from metrology.io.clouds import CLOUD_SUFFIXES

    clouds = tuple(sorted(CLOUD_SUFFIXES))
    return {"--plane": (".json",) + clouds, "--extent": (".json",) + clouds, "CLOUD": clouds,
            "PANEL": tuple("." + f for f in MESH_FORMATS)}.get(label)


MESH_FORMATS = ("stl", "obj", "ply", "off", "glb", "gltf", "step", "stp")


def check_input(label: str, value) -> None:
    """One wording for every command: ``FILE: no such file (LABEL)``, ``FILE: a folder, not a file
    (LABEL)``, and for an input whose suffix picks its reader, the suffixes accepted."""
    path = Path(value)
    if not path.exists():
        fail(f"{value}: no such file ({label})")
    if path.is_dir():
        fail(f"{value}: a folder, not a file ({label})")
    ok = _accepted(label)
    if ok is not None and path.suffix.lower() not in ok:
        fail(f"{value}: unknown extension {path.suffix or '(none)'!r} for {label}; expected one of {', '.join(ok)}")


def format_suffix(label: str, fmt: str | None, known, what: str):
    """The ``suffix(data)`` callable for a stream whose format ``--format`` names or its first
    bytes show (PLY, PCD, ...); fails naming ``--format`` when neither does."""

    def suffix(data):
        if fmt is not None:
            return "." + fmt.lower().lstrip(".")
        s = sniff_suffix(data)
        if s is None or s not in known:
            fail(f"{label} -: the {what} on stdin has no header that names its format; give --format "
                 f"({', '.join(sorted(k[1:] for k in known))})")
        return s

    return suffix


def plane_suffix(data: bytes) -> str:
    """``--plane -``: a fit-plane JSON or a datum cloud in PLY or PCD (the formats with a header)."""
    s = sniff_suffix(data)
    if s not in (".json", ".ply", ".pcd"):
        fail("--plane -: stdin holds neither a plane JSON nor a PLY/PCD cloud (give a text cloud as a file)")
    return s
