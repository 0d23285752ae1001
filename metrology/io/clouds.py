"""Point-cloud readers: PLY, PCD, E57, XYZ/XYZN/PTS and CSV/TXT, as ``(m, 3)`` arrays in mm.

Which reader reads what:

- ``.ply`` (ASCII and binary) is read by Open3D, after metro has checked the header
  against the file's length: Open3D (RPly) returns a truncated binary PLY with its
  missing vertices filled from uninitialised memory.
- ``.pcd``: ``binary_compressed`` is read by Open3D; ``ascii`` and ``binary`` are read
  by metro, because Open3D 0.20 reads 8-byte (double) binary coordinates as zeros.
- ``.e57`` is read by the optional package ``pye57`` (E57 stores metres; metro converts to
  mm). All scans of the file are read, each placed in the file's frame by its pose.
- ``.xyz``, ``.xyzn``, ``.xyzrgb``, ``.pts``, ``.csv`` and ``.txt`` are read by metro's own
  text parser. Open3D reads ``.xyz``/``.xyzn``/``.pts`` too, but skips a malformed line
  without a word (``4 5 abc`` simply disappears from the cloud); a metrology tool must not
  drop measurements silently, so metro parses text itself and names the bad line.

Text files: one point per line; blank lines and lines starting with ``#`` or ``//`` are
skipped. Fields are separated by ``;``, ``,`` or white space (whichever the first data
line uses, in that order of precedence); with ``;`` a decimal comma (``12,5``) is
accepted. A first line that names its columns is a header: the x, y and z columns are the
ones named ``x``, ``y``, ``z`` (case-insensitive; a unit in brackets and words around
them are ignored: ``X [mm]``, ``Point_X``, ``pos x``). Without a header, x, y and z are
the first three numeric columns of the first data line (a leading point-name column such
as ``P1`` is skipped); other columns are ignored. A ``.pts`` file may start with a line
holding the point count, which is then checked.

Coordinates are returned as read: metro treats them as mm in the cloud's own frame
(except E57, converted from metres).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
from pathlib import Path

import numpy as np

__all__ = ["read_cloud", "cloud_format", "write_ply", "CLOUD_SUFFIXES"]

#: file suffix -> format name
CLOUD_SUFFIXES = {
    ".ply": "PLY",
    ".pcd": "PCD",
    ".e57": "E57",
    ".xyz": "XYZ",
    ".xyzn": "XYZN",
    ".xyzrgb": "XYZRGB",
    ".pts": "PTS",
    ".csv": "CSV",
    ".txt": "TXT",
}
_TEXT = {".xyz", ".xyzn", ".xyzrgb", ".pts", ".csv", ".txt"}
#: E57 stores cartesian coordinates in metres (ASTM E2807)
_MM_PER_M = 1000.0
_CHUNK = 1 << 20
_AXIS_TOKEN = re.compile(r"[^a-z0-9]+")
_WHITE_FIELD = re.compile(r"\"[^\"]*\"|'[^']*'|\S+")
_UNIT_ONLY = re.compile(r"[\[(].*[\])]")


def write_ply(path, points, comments=()) -> None:
    """Write ``points (m, 3)`` float, mm, as a binary little-endian PLY with double x, y, z,
    atomically; ``comments`` are header comment lines."""
    from metrology.io.atomic import atomic_path

    P = np.ascontiguousarray(points, dtype="<f8")
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"{path}: points must be (m, 3), got shape {P.shape}")
    header = ("ply\nformat binary_little_endian 1.0\n" + "".join(f"comment {c}\n" for c in comments)
              + f"element vertex {len(P)}\nproperty double x\nproperty double y\nproperty double z\nend_header\n")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(P.tobytes())


def cloud_format(path) -> str:
    """The format name of ``path`` from its suffix (``"PLY"``, ``"CSV"``, ...); raise if unknown."""
    suffix = Path(path).suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        known = ", ".join(sorted(CLOUD_SUFFIXES))
        raise ValueError(f"{path}: unknown point-cloud extension {suffix or '(none)'!r}; expected one of {known}")
    return CLOUD_SUFFIXES[suffix]


def read_cloud(path):
    """Read a point cloud file.

    Parameters
    ----------
    path : str or os.PathLike
        ``.ply``, ``.pcd``, ``.e57``, ``.xyz``, ``.xyzn``, ``.xyzrgb``, ``.pts``, ``.csv`` or ``.txt``.

    Returns
    -------
    points : (m, 3) float, mm, cloud frame
        m >= 3, all finite. For PLY/PCD this is a view of Open3D's buffer (no copy).

    Raises
    ------
    ValueError
        One line naming the file and the problem: missing or empty file, unknown
        extension, unreadable content, a non-numeric field (with its line and column),
        NaN or inf (with its line or point number), fewer than 3 points.
    """
    fmt = cloud_format(path)
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{path}: no such file")
    if p.is_dir():
        raise ValueError(f"{path}: is a directory, not a point-cloud file")
    if p.stat().st_size == 0:
        raise ValueError(f"{path}: empty file")
    suffix = p.suffix.lower()
    if suffix == ".ply":
        expected = _ply_vertex_count(path)
        points = _read_open3d(path, fmt)
        if expected is not None and len(points) != expected:
            raise ValueError(f"{path}: the header declares {expected} vertices, {len(points)} were read")
    elif suffix == ".pcd":
        points = _read_pcd(path)
    elif suffix == ".e57":
        points = _read_e57(path)
    else:
        points = _read_text(path, suffix)
    return _checked(points, path)


def _checked(points, path):
    """Check shape, count and finiteness of points read from a binary format."""
    m = len(points)
    if m == 0:
        raise ValueError(f"{path}: no points in the file")
    if m < 3:
        raise ValueError(f"{path}: {m} point{'s' if m != 1 else ''}, need at least 3")
    for start in range(0, m, _CHUNK):
        bad = ~np.isfinite(points[start : start + _CHUNK]).all(axis=1)
        if bad.any():
            i = start + int(np.argmax(bad))
            raise ValueError(f"{path}: point {i + 1} is {points[i].tolist()}: coordinates must be finite (no NaN or inf)")
    return points


def _read_open3d(path, fmt):
    from metrology.io._o3d import open3d

    o3d = open3d()
    cloud = o3d.io.read_point_cloud(os.fspath(path), format="auto", remove_nan_points=False, remove_infinite_points=False)
    if not cloud.has_points():
        raise ValueError(f"{path}: no points read (not a valid {fmt} file, or it holds no vertices)")
    return np.asarray(_CloudBuffer(cloud))


_PLY_SIZES = {
    "char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
    "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8,
}


def _ply_vertex_count(path):
    """Check a PLY header against the file's length; return the declared vertex count.

    Open3D (RPly) reports a truncated file on stderr but still returns the declared
    number of vertices, the missing ones filled with whatever was in memory; metro
    checks the length itself. Returns None when the header is not one it can check.
    """
    with open(path, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' ... 'end_header' header)")
    nl = head.find(b"\n", end)
    body_start = (nl + 1) if nl >= 0 else len(head)
    lines = head[:end].decode("ascii", "replace").splitlines()
    fmt, elements = None, []
    for line in lines:
        t = line.split()
        if not t:
            continue
        if t[0] == "format" and len(t) > 1:
            fmt = t[1]
        elif t[0] == "element" and len(t) == 3:
            try:
                elements.append([t[1], int(t[2]), 0])
            except ValueError:
                raise ValueError(f"{path}: bad PLY header line {line!r}") from None
        elif t[0] == "property" and elements:
            if t[1] == "list" or t[1] not in _PLY_SIZES:
                elements[-1][2] = None  # variable or unknown size: cannot check
            elif elements[-1][2] is not None:
                elements[-1][2] += _PLY_SIZES[t[1]]
    vertex = [e for e in elements if e[0] == "vertex"]
    if not vertex:
        raise ValueError(f"{path}: the PLY header declares no vertex element")
    count = vertex[0][1]
    if fmt in ("binary_little_endian", "binary_big_endian") and elements[0][0] == "vertex" and elements[0][2]:
        have = (Path(path).stat().st_size - body_start) // elements[0][2]
        if have < count:
            raise ValueError(f"{path}: truncated: the header declares {count} vertices, the file holds {have}")
    return count


_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
              ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def _read_pcd(path):
    """PCD: ``ascii`` and ``binary`` read by metro, ``binary_compressed`` by Open3D.

    Open3D 0.20 reads the x, y, z of a binary PCD stored as 8-byte floats as zeros,
    silently; metro reads uncompressed PCD itself, exactly, whatever the field types.
    """
    with open(path, "rb") as fh:
        raw = fh.read(65536)
    header, pos = {}, 0
    lines = raw.split(b"\n")
    data_mode = None
    for line in lines:
        pos += len(line) + 1
        text = line.decode("ascii", "replace").strip()
        if not text or text.startswith("#"):
            continue
        key, _, rest = text.partition(" ")
        header[key.upper()] = rest.split()
        if key.upper() == "DATA":
            data_mode = rest.strip().lower()
            break
    if data_mode is None or "FIELDS" not in header:
        raise ValueError(f"{path}: not a PCD file (no FIELDS ... DATA header)")
    fields = header["FIELDS"]
    n_f = len(fields)
    sizes = [int(x) for x in header.get("SIZE", ["4"] * n_f)]
    types = [x.upper() for x in header.get("TYPE", ["F"] * n_f)]
    counts = [int(x) for x in header.get("COUNT", ["1"] * n_f)]
    try:
        npts = int(header["POINTS"][0]) if "POINTS" in header else int(header["WIDTH"][0]) * int(header["HEIGHT"][0])
    except (KeyError, ValueError, IndexError):
        raise ValueError(f"{path}: the PCD header gives no point count (POINTS or WIDTH x HEIGHT)") from None
    if not all(a in fields for a in "xyz"):
        raise ValueError(f"{path}: the PCD has no x, y, z fields (FIELDS {' '.join(fields)})")
    if not (len(sizes) == len(types) == len(counts) == n_f):
        raise ValueError(f"{path}: the PCD header's FIELDS, SIZE, TYPE and COUNT disagree")
    if data_mode == "binary_compressed":
        if any(sizes[fields.index(a)] != 4 for a in "xyz"):
            raise ValueError(f"{path}: binary_compressed PCD with 8-byte coordinates is not supported; save it as binary")
        return _read_open3d(path, "PCD")
    if data_mode == "ascii":
        text = raw[pos:].decode("utf-8", "replace") if Path(path).stat().st_size <= len(raw) else None
        if text is None:
            with open(path, "rb") as fh:
                fh.seek(pos)
                text = fh.read().decode("utf-8", "replace")
        body = text.splitlines()
        first_line = raw[:pos].count(b"\n")  # header lines before the data
        rows = [i for i, line in enumerate(body) if line.strip()]
        col = np.cumsum([0] + counts)
        cols = tuple(int(col[fields.index(a)]) for a in "xyz")
        if len(rows) != npts:
            raise ValueError(f"{path}: the header declares {npts} points, the file holds {len(rows)}")
        lines_all = [""] * first_line + body
        data = [first_line + i for i in rows]
        pts = _fast_parse(lines_all, data, None, cols)
        if pts is None:
            pts = _slow_parse(path, lines_all, data, None, cols, False)
        return pts
    if data_mode != "binary":
        raise ValueError(f"{path}: unknown PCD DATA mode {data_mode!r}")
    try:
        dtype = np.dtype([(f"f{i}", "<" + _PCD_TYPES[(t, z)], (c,) if c > 1 else ()) for i, (t, z, c) in enumerate(zip(types, sizes, counts))])
    except KeyError:
        raise ValueError(f"{path}: unsupported PCD field types {types} / sizes {sizes}") from None
    have = (Path(path).stat().st_size - pos) // dtype.itemsize
    if have < npts:
        raise ValueError(f"{path}: truncated: the header declares {npts} points, the file holds {have}")
    rec = np.fromfile(path, dtype=dtype, count=npts, offset=pos)
    pts = np.empty((npts, 3))
    for j, a in enumerate("xyz"):
        pts[:, j] = rec[f"f{fields.index(a)}"]
    return pts


class _CloudBuffer:
    """Exposes an Open3D cloud's point buffer to numpy and keeps the cloud alive.

    ``np.asarray(cloud.points)`` is a view that does not keep ``cloud`` alive: once the
    cloud is collected the view reads freed memory. An array made from this object has
    it as its ``base``, so the cloud lives as long as any view of it. No copy is made
    (a copy would double the peak memory of a 10^7-point fit).
    """

    def __init__(self, cloud):
        self.cloud = cloud
        self.__array_interface__ = np.asarray(cloud.points).__array_interface__


def _read_e57(path):
    try:
        import pye57
    except ImportError:
        raise ValueError(f"{path}: reading E57 needs the optional package pye57 (pip install pye57)") from None
    e57_error = getattr(getattr(pye57, "libe57", None), "E57Exception", RuntimeError)
    try:
        with _quiet_stderr():  # libE57Format prints a multi-line report of its own
            e57 = pye57.E57(os.fspath(path))
            parts = []
            for i in range(e57.scan_count):
                scan = e57.read_scan(i, ignore_missing_fields=True)
                xyz = np.column_stack([scan["cartesianX"], scan["cartesianY"], scan["cartesianZ"]]).astype(float)
                invalid = scan.get("cartesianInvalidState")
                if invalid is not None and len(invalid) == len(xyz):
                    xyz = xyz[np.asarray(invalid) == 0]
                parts.append(xyz)
    except (KeyError, RuntimeError, OSError, e57_error) as exc:
        msg = (str(exc).strip().splitlines() or [type(exc).__name__])[0].strip()
        raise ValueError(f"{path}: not a readable E57 point cloud with cartesian coordinates ({msg})") from None
    points = np.concatenate(parts) if parts else np.empty((0, 3))
    return points * _MM_PER_M


@contextlib.contextmanager
def _quiet_stderr():
    """Silence file descriptor 2 (C++ libraries' own diagnostics) for the block."""
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # no real stderr (e.g. captured by a test runner)
        yield
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


# ---------------------------------------------------------------------------------------
# text formats


def _is_data(line: str) -> bool:
    s = line.strip()
    return bool(s) and not s.startswith("#") and not s.startswith("//")


def _split(line: str, delim):
    s = line.strip()
    fields = _WHITE_FIELD.findall(s) if delim is None else [f.strip() for f in s.split(delim)]
    return [f.strip("\"'") for f in fields]


def _number(field: str, decimal_comma: bool):
    """``float(field)`` or ``None`` when it is not a number (NaN/inf parse: checked later)."""
    if decimal_comma:
        field = field.replace(",", ".")
    try:
        return float(field)
    except ValueError:
        return None


def _axis_name(field: str):
    """``'x'``, ``'y'`` or ``'z'`` if the header field names that coordinate, else ``None``."""
    name = re.sub(r"[\[(].*?[\])]", " ", field.lower())
    tokens = [t for t in _AXIS_TOKEN.split(name) if t]
    hits = {t for t in tokens if t in ("x", "y", "z")}
    return hits.pop() if len(hits) == 1 else None


def _layout(path, first_fields, decimal_comma, lineno):
    """Decide whether the first data line is a header, and which columns hold x, y, z."""
    names = [_axis_name(f) for f in first_fields]
    numeric = [_number(f, decimal_comma) is not None for f in first_fields]
    named = {a: [i for i, n in enumerate(names) if n == a] for a in "xyz"}
    has_names = all(named[a] for a in "xyz")
    header = has_names or not any(numeric)
    if header:
        if not has_names:
            shown = ", ".join(repr(f) for f in first_fields)
            raise ValueError(f"{path}: line {lineno} is a header without x, y, z columns (got {shown}); name the columns x, y, z")
        cols = []
        for a in "xyz":
            if len(named[a]) > 1:
                exact = [i for i in named[a] if first_fields[i].strip().lower() == a]
                if len(exact) != 1:
                    shown = ", ".join(repr(first_fields[i]) for i in named[a])
                    raise ValueError(f"{path}: header names {a} more than once ({shown})")
                named[a] = exact
            cols.append(named[a][0])
        return True, tuple(cols)
    cols = [i for i, ok in enumerate(numeric) if ok][:3]
    if len(cols) < 3:
        raise ValueError(f"{path}: line {lineno} has {len(cols)} numeric field(s), expected x, y, z")
    return False, tuple(cols)


def _read_text(path, suffix):
    try:
        with open(path, encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except UnicodeDecodeError:
        with open(path, encoding="latin-1") as fh:
            lines = fh.read().splitlines()
    data = [i for i, line in enumerate(lines) if _is_data(line)]
    if not data:
        raise ValueError(f"{path}: no points in the file (only blank or comment lines)")
    expected = None
    if suffix == ".pts":
        head = lines[data[0]].split()
        if len(head) == 1 and re.fullmatch(r"\d+", head[0]):
            expected = int(head[0])
            data = data[1:]
            if not data:
                raise ValueError(f"{path}: no points in the file (only the point count {expected})")
    first = lines[data[0]].strip()
    delim = ";" if ";" in first else ("," if "," in first else None)
    fields = _split(first, delim)
    if delim is None and not all(_number(f, False) is not None for f in fields):
        # a white-space header may carry its units as separate fields: "X [mm] Y [mm] Z [mm]"
        fields = [f for f in fields if not _UNIT_ONLY.fullmatch(f)]
    # with ';' a ',' inside a field is a decimal comma (look past a possible header line)
    decimal_comma = delim == ";" and any("," in line for line in (lines[i] for i in data[:2]))
    header, cols = _layout(path, fields, decimal_comma, data[0] + 1)
    if header:
        data = data[1:]
    if expected is not None and expected != len(data):
        raise ValueError(f"{path}: the first line says {expected} points, the file holds {len(data)}")
    if not data:
        raise ValueError(f"{path}: no points in the file (a header only)")
    if len(data) < 3:
        raise ValueError(f"{path}: {len(data)} point{'s' if len(data) != 1 else ''}, need at least 3")
    points = None
    if not decimal_comma:
        points = _fast_parse(lines, data, delim, cols)
    if points is None:
        points = _slow_parse(path, lines, data, delim, cols, decimal_comma)
    return points


def _fast_parse(lines, data, delim, cols):
    """numpy's C parser over the data lines; ``None`` on any problem (the slow path names it)."""
    try:
        points = np.loadtxt(
            (lines[i] for i in data), delimiter=delim, usecols=cols, dtype=float, ndmin=2, quotechar='"'
        )
    except (ValueError, IndexError):
        return None
    if points.shape != (len(data), 3) or not np.isfinite(points).all():
        return None
    return points


def _slow_parse(path, lines, data, delim, cols, decimal_comma):
    """Parse line by line; raise naming the first bad line, column and field."""
    out = np.empty((len(data), 3))
    need = max(cols) + 1
    for k, i in enumerate(data):
        fields = _split(lines[i], delim)
        if len(fields) < need:
            raise ValueError(f"{path}: line {i + 1}: {len(fields)} field(s), expected at least {need} (x, y, z in columns {', '.join(str(c + 1) for c in cols)})")
        for j, c in enumerate(cols):
            v = _number(fields[c], decimal_comma)
            if v is None:
                raise ValueError(f"{path}: line {i + 1}, column {c + 1}: {fields[c]!r} is not a number ({'xyz'[j]} expected)")
            if not math.isfinite(v):
                raise ValueError(f"{path}: line {i + 1}, column {c + 1}: {fields[c]!r}: coordinates must be finite (no NaN or inf)")
            out[k, j] = v
    return out
