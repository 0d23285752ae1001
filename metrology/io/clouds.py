"""Point-cloud readers: PLY, PCD, E57, XYZ/XYZN/PTS and CSV/TXT, as ``(m, 3)`` arrays in mm.

Two entry points:

- :func:`read_cloud` ``(path) -> (m, 3) float, mm``: strict, any NaN or inf refused;
- :func:`read_cloud_checked` ``(path, *, units=None, nonfinite="drop", min_points=3,
  hint=True) -> CloudRead``: drops NaN points (missing returns of organized depth scans)
  and counts them in ``n_dropped_nonfinite``, scales ``units`` ("mm", "m", "in") to mm,
  and returns a :class:`metrology.io.units.UnitsHint` saying whether the extent and the
  point spacing look like metres (the rule is in :mod:`metrology.io.units`).

Which reader reads what (every malformed file is refused with one ``ValueError``:
``<file>: line <n>[, column <c>]: <what was found>, expected <what>``, or for binary
bodies the byte or point count that is wrong):

- ``.ply`` ASCII is read by metro's strict parser (:mod:`metrology.io.ply`): Open3D's
  (RPly's) ASCII reader, on a bad token or a short row, returns the declared number of
  points padded with uninitialised memory. Binary PLY is read by numpy after metro has
  checked the header's grammar and the body's length against it (RPly fills a truncated
  file from uninitialised memory); only a binary vertex element with list properties goes
  to Open3D (its console output to stderr).
- ``.pcd``: ``binary_compressed`` is read by Open3D; ``ascii`` (as strictly as ASCII PLY)
  and ``binary`` (length checked both ways) by metro, because Open3D 0.20 reads 8-byte
  (double) binary coordinates as zeros.
- ``.e57`` is read by the optional package ``pye57`` (E57 stores metres; metro converts to
  mm). All scans of the file are read, each placed in the file's frame by its pose.
- ``.xyz``, ``.xyzn``, ``.xyzrgb``, ``.pts``, ``.csv`` and ``.txt`` are read by metro's own
  text parser (:mod:`metrology.io.text_clouds`). Open3D reads ``.xyz``/``.xyzn``/``.pts``
  too, but skips a malformed line without a word (``4 5 abc`` simply disappears from the
  cloud); a metrology tool must not drop measurements silently.

Text files: one point per line; blank lines and lines starting with ``#`` or ``//`` are
skipped. Fields are separated by ``;``, ``,`` or white space (whichever the first data
line uses, in that order of precedence); with ``;`` a decimal comma (``12,5``) is
accepted. A first line that names its columns is a header: the x, y and z columns are the
ones named ``x``, ``y``, ``z`` (case-insensitive; a unit in brackets and words around
them are ignored: ``X [mm]``, ``Point_X``, ``pos x``). Without a header, x, y and z are
the first three numeric columns of the first data line (a leading point-name column such
as ``P1`` is skipped); other columns are ignored, but every data line must hold as many
fields as the first. A ``.pts`` file may start with a line holding the point count,
which is then checked.

NaN and inf: NaN marks a missing return (organized scans write it for pixels without
depth); :func:`read_cloud_checked` drops such points and counts them. An infinite
coordinate is not a measurement and is always refused, with its line or point number.

Coordinates are returned as read unless ``units`` says otherwise: metro treats them as
mm in the cloud's own frame (except E57, converted from metres).
"""

from __future__ import annotations

import contextlib
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metrology.io.ply import (PAD, PlyElement, PlyProperty, body_lines, check_binary_size, parse_rows, read_ascii_ply,
                              read_binary_vertices, read_ply_header, vertex_element)
from metrology.io.text_clouds import read_text_cloud
from metrology.io.units import UnitsHint, infer_units, mm_per_unit

__all__ = ["read_cloud", "read_cloud_checked", "CloudRead", "cloud_format", "write_ply", "CLOUD_SUFFIXES"]

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


@dataclass(frozen=True)
class CloudRead:
    """A point cloud as read, with what the reader did to it.

    Attributes
    ----------
    points : (m, 3) float, mm, cloud frame
        All finite, m >= ``min_points``.
    n_in_file : int
        Points the file holds (before dropping).
    n_dropped_nonfinite : int
        Points dropped because a coordinate is NaN (missing returns of organized scans).
    units : str
        The unit the file was read in (``"mm"`` unless the caller said otherwise; E57: ``"m"``).
    units_hint : UnitsHint or None
        What the cloud's extent and spacing suggest (:func:`metrology.io.units.infer_units`),
        computed on the file's numbers; ``None`` when not asked for.
    ignored_lines : tuple of int
        File lines (1-based) read past after a PLY's last element (none parses as a vertex
        row; RPly and PCL read past them too, :func:`metrology.io.ply.read_ascii_ply`).
    """

    points: np.ndarray
    n_in_file: int
    n_dropped_nonfinite: int
    units: str
    units_hint: UnitsHint | None = None
    ignored_lines: tuple = ()

    def to_dict(self) -> dict:
        return {"n_points": len(self.points), "n_in_file": self.n_in_file,
                "n_dropped_nonfinite": self.n_dropped_nonfinite, "units": self.units,
                "units_hint": None if self.units_hint is None else self.units_hint.to_dict(),
                "ignored_lines": list(self.ignored_lines)}


def read_cloud(path):
    """Read a point cloud file, strictly: any NaN or inf coordinate is refused.

    Parameters
    ----------
    path : str or os.PathLike
        ``.ply``, ``.pcd``, ``.e57``, ``.xyz``, ``.xyzn``, ``.xyzrgb``, ``.pts``, ``.csv`` or ``.txt``.

    Returns
    -------
    points : (m, 3) float, mm, cloud frame
        m >= 3, all finite. For binary PLY and compressed PCD this is a view of Open3D's
        buffer (no copy).

    Raises
    ------
    ValueError
        One line naming the file and the problem: missing or empty file, unknown
        extension, a malformed header or row (with its line and value), NaN or inf
        (with its line or point number), fewer than 3 points.

    See Also
    --------
    read_cloud_checked : drops NaN points with a count, converts units, guesses units.
    """
    return read_cloud_checked(path, nonfinite="refuse", hint=False).points


def read_cloud_checked(path, *, units=None, nonfinite="drop", min_points=3, hint=True) -> CloudRead:
    """Read a point cloud file and say what was done to it.

    Parameters
    ----------
    path : str or os.PathLike
        As :func:`read_cloud`.
    units : {None, "mm", "m", "in"}
        The unit of the file's numbers; the points are scaled to mm. ``None`` means mm
        (E57 files are in metres by definition and take ``None`` or ``"m"``).
    nonfinite : {"drop", "refuse"}
        ``"drop"``: points with a NaN coordinate (missing returns of organized depth
        scans) are dropped and counted; ``"refuse"``: any is an error. An infinite
        coordinate is always refused (it is not a measurement).
    min_points : int
        Fewest points left after dropping; fewer is an error.
    hint : bool
        Compute :attr:`CloudRead.units_hint` (a k-d tree on up to 2 x 10^4 points: ~0.1 s).

    Returns
    -------
    CloudRead
    """
    if nonfinite not in ("drop", "refuse"):
        raise ValueError(f"nonfinite {nonfinite!r}: expected 'drop' or 'refuse'")
    scale = 1.0 if units is None else mm_per_unit(units)
    fmt = cloud_format(path)
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{path}: no such file")
    if p.is_dir():
        raise ValueError(f"{path}: is a directory, not a point-cloud file")
    if p.stat().st_size == 0:
        raise ValueError(f"{path}: empty file")
    suffix = p.suffix.lower()
    allow_nan = nonfinite == "drop"
    ignored = ()
    if suffix == ".ply":
        points, ignored = _read_ply(path)
    elif suffix == ".pcd":
        points = _read_pcd(path)
    elif suffix == ".e57":
        if units not in (None, "m"):
            raise ValueError(f"{path}: E57 stores metres (ASTM E2807); units={units!r} does not apply")
        points, scale, units = _read_e57(path), _MM_PER_M, "m"
    else:
        points = read_text_cloud(path, suffix, allow_nan)
    n_file = len(points)
    points, dropped = _finite(points, path, allow_nan, fmt)
    m = len(points)
    if m == 0:
        raise ValueError(f"{path}: no points in the file" + (f" ({dropped} NaN points dropped)" if dropped else ""))
    if m < min_points:
        why = f" of {n_file} ({dropped} with NaN dropped)" if dropped else ""
        raise ValueError(f"{path}: {m} point{'s' if m != 1 else ''}{why}, need at least {min_points}")
    guess = infer_units(points) if hint and suffix != ".e57" else None
    if scale != 1.0:
        points = points * scale
    return CloudRead(points, n_file, dropped, units or "mm", guess, ignored)


def _finite(points, path, allow_nan, fmt):
    """Drop (``allow_nan``) or refuse points with a NaN coordinate; always refuse inf."""
    m = len(points)
    keep = None
    ones = np.ones(points.shape[1]) if points.ndim == 2 else None
    for start in range(0, m, _CHUNK):
        block = points[start : start + _CHUNK]
        with np.errstate(over="ignore", invalid="ignore"):  # huge finite values may overflow the sum
            if np.isfinite(block @ ones).all():  # a NaN or inf makes its row's sum non-finite (BLAS: fast)
                continue
        ok = np.isfinite(block).all(axis=1)
        if ok.all():  # finite values whose sum overflowed
            continue
        bad = ~ok if not allow_nan else np.isinf(block).any(axis=1)
        if bad.any():
            i = start + int(np.argmax(bad))
            raise ValueError(f"{path}: point {i + 1} is {points[i].tolist()}: coordinates must be finite (no NaN or inf)"
                             if not allow_nan else f"{path}: point {i + 1} is {points[i].tolist()}: coordinates must not be infinite")
        if keep is None:
            keep = np.ones(m, dtype=bool)
        keep[start : start + _CHUNK] = ok
    if keep is None:
        return points, 0
    return points[keep], int(m - keep.sum())


def _read_open3d(path, fmt):
    from metrology.io._o3d import open3d

    o3d = open3d()
    with _redirect_fd(1, 2):  # Open3D's own console messages never reach stdout
        cloud = o3d.io.read_point_cloud(os.fspath(path), format="auto", remove_nan_points=False, remove_infinite_points=False)
    if not cloud.has_points():
        raise ValueError(f"{path}: no points read (not a valid {fmt} file, or it holds no vertices)")
    return np.asarray(_CloudBuffer(cloud))


def _read_ply(path):
    """PLY by metro's readers: ASCII by the strict parser, binary by numpy after the header
    and the body's length are checked. Returns ``(points, ignored_lines)``.

    Open3D is not needed (its import alone takes longer than reading 10^6 binary points);
    it reads only a binary vertex element holding list properties, which metro does not lay out.
    """
    header = read_ply_header(path)
    if header.format == "ascii":
        return read_ascii_ply(path, header)
    check_binary_size(path, header)
    vertex = vertex_element(header)
    if vertex.count == 0:
        return np.empty((0, 3)), ()
    if vertex.row_bytes is None:
        points = _read_open3d(path, "PLY")
        if len(points) != vertex.count:
            raise ValueError(f"{path}: the header declares {vertex.count} vertices, {len(points)} were read")
        return points, ()
    return read_binary_vertices(path, header), ()


#: PCL's padding field: its bytes (binary) or tokens (ASCII) are skipped, whatever its TYPE and
#: SIZE, as PCL's ``PCDReader`` skips them (PCL's ``ComplexPCDFileASCII`` test: ``_`` of TYPE F, SIZE 1)
_PCD_PAD = "_"
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

    def ints(key, default):
        vals = header.get(key, default)
        if not vals or not all(v.isdigit() for v in vals):
            raise ValueError(f"{path}: header line {key} {' '.join(vals)!r}, expected non-negative integers")
        return [int(v) for v in vals]

    sizes = ints("SIZE", ["4"] * n_f)
    types = [x.upper() for x in header.get("TYPE", ["F"] * n_f)]
    counts = ints("COUNT", ["1"] * n_f)
    if "POINTS" not in header and not ("WIDTH" in header and "HEIGHT" in header):
        raise ValueError(f"{path}: the PCD header gives no point count (POINTS or WIDTH x HEIGHT)")
    npts = ints("POINTS", None)[0] if "POINTS" in header else ints("WIDTH", None)[0] * ints("HEIGHT", None)[0]
    if not all(a in fields for a in "xyz"):
        raise ValueError(f"{path}: the PCD has no x, y, z fields (FIELDS {' '.join(fields)})")
    if not (len(sizes) == len(types) == len(counts) == n_f):
        raise ValueError(f"{path}: the PCD header's FIELDS, SIZE, TYPE and COUNT disagree")
    if data_mode == "binary_compressed":
        if any(sizes[fields.index(a)] != 4 for a in "xyz"):
            raise ValueError(f"{path}: binary_compressed PCD with 8-byte coordinates is not supported; save it as binary")
        return _read_open3d(path, "PCD")
    if data_mode == "ascii":
        return _read_pcd_ascii(path, pos, raw[:pos].count(b"\n"), fields, types, sizes, counts, npts)
    if data_mode != "binary":
        raise ValueError(f"{path}: unknown PCD DATA mode {data_mode!r}")
    try:
        dtype = np.dtype([(f"f{i}", f"V{z}" if name == _PCD_PAD else "<" + _PCD_TYPES[(t, z)], (c,) if c > 1 else ())
                          for i, (name, t, z, c) in enumerate(zip(fields, types, sizes, counts))])
    except KeyError:
        raise ValueError(f"{path}: unsupported PCD field types {types} / sizes {sizes}") from None
    have = (Path(path).stat().st_size - pos) // dtype.itemsize
    if have < npts:
        raise ValueError(f"{path}: truncated: the header declares {npts} points, the file holds {have}")
    extra = Path(path).stat().st_size - pos - npts * dtype.itemsize
    if extra > 0:
        raise ValueError(f"{path}: {extra} byte(s) after the {npts} declared points, expected the end of the file")
    rec = np.fromfile(path, dtype=dtype, count=npts, offset=pos)
    pts = np.empty((npts, 3))
    for j, a in enumerate("xyz"):
        pts[:, j] = rec[f"f{fields.index(a)}"]
    return pts


def _read_pcd_ascii(path, offset, header_lines, fields, types, sizes, counts, npts):
    """ASCII PCD, strictly: one row per point, each with exactly the declared values, each
    value of its declared TYPE and SIZE; ``nan`` allowed in F fields (organized scans)."""
    props = []
    for name, t, z, c in zip(fields, types, sizes, counts):
        if name == _PCD_PAD:
            props += [PlyProperty(f"_[{i}]", PAD) for i in range(c)]
            continue
        code = _PCD_TYPES.get((t, z))
        if code is None:
            raise ValueError(f"{path}: unsupported PCD field type {t} of size {z} (field {name!r})")
        props += [PlyProperty(name if c == 1 else f"{name}[{i}]", code) for i in range(c)]
    lines = body_lines(path, offset)
    while lines and not lines[-1].strip():
        lines.pop()
    if len(lines) != npts:
        raise ValueError(f"{path}: the header declares {npts} points, the file holds {len(lines)}")
    element = PlyElement("point", npts, tuple(props), header_lines)
    values = parse_rows(path, lines, 0, element, header_lines + 1)
    col = np.cumsum([0] + counts)
    return values[:, [int(col[fields.index(a)]) for a in "xyz"]]


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
        with _redirect_fd(2, None):  # libE57Format prints a multi-line report of its own
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
    return points  # metres


@contextlib.contextmanager
def _redirect_fd(fd_no, target):
    """Send file descriptor ``fd_no`` (C++ libraries' own console output) to descriptor
    ``target`` (``None``: /dev/null) for the block."""
    stream = sys.stdout if fd_no == 1 else sys.stderr
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):  # no real descriptor (e.g. captured by a test runner)
        yield
        return
    stream.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno() if target is None else target, fd)
            yield
    finally:
        stream.flush()
        os.dup2(saved, fd)
        os.close(saved)
