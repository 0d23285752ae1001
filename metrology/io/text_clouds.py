"""Text point clouds (XYZ, XYZN, XYZRGB, PTS, CSV, TXT): metro's own parser, which names the bad line.

The layout rules are those of :mod:`metrology.io.clouds` (its module docstring). Every data
row must hold as many fields as the first one; ``nan`` in a coordinate is accepted only
when the caller drops NaN points (and counts them); ``inf`` is always refused.
"""

from __future__ import annotations

import math
import re

import numpy as np

_AXIS_TOKEN = re.compile(r"[^a-z0-9]+")
_WHITE_FIELD = re.compile(r"\"[^\"]*\"|'[^']*'|\S+")
_UNIT_ONLY = re.compile(r"[\[(].*[\])]")




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


def read_text_cloud(path, suffix, allow_nan=False):
    """x, y, z of a text cloud as ``(m, 3) float`` (file units); NaN kept when ``allow_nan``."""
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
    n_fields = len(_split(lines[data[0]], delim))
    points = None
    if not decimal_comma and all(_number(f, False) is not None for f in _split(lines[data[0]], delim)):
        points = fast_parse(lines, data, delim, cols, allow_nan, n_fields)
    if points is None:
        points = slow_parse(path, lines, data, delim, cols, decimal_comma, allow_nan, n_fields)
    return points


def fast_parse(lines, data, delim, cols, allow_nan=False, n_fields=None):
    """numpy's C parser over all-numeric data lines (it refuses rows of another length);
    ``None`` on any problem (the slow path names it)."""
    try:
        points = np.loadtxt((lines[i] for i in data), delimiter=delim, dtype=float, ndmin=2, quotechar='"', comments=None)
    except (ValueError, IndexError):
        return None
    if len(points) != len(data) or (n_fields is not None and points.shape[1] != n_fields):
        return None
    points = points[:, list(cols)]
    if np.isinf(points).any() or (not allow_nan and np.isnan(points).any()):
        return None
    return points


def slow_parse(path, lines, data, delim, cols, decimal_comma, allow_nan=False, n_fields=None):
    """Parse line by line; raise naming the first bad line, column and field."""
    out = np.empty((len(data), 3))
    need = max(cols) + 1
    for k, i in enumerate(data):
        fields = _split(lines[i], delim)
        if len(fields) < need:
            raise ValueError(f"{path}: line {i + 1}: {len(fields)} field(s), expected at least {need} (x, y, z in columns {', '.join(str(c + 1) for c in cols)})")
        if n_fields is not None and len(fields) != n_fields:
            raise ValueError(f"{path}: line {i + 1}: {len(fields)} field(s), expected {n_fields} as on line {data[0] + 1}")
        for j, c in enumerate(cols):
            v = _number(fields[c], decimal_comma)
            if v is None:
                raise ValueError(f"{path}: line {i + 1}, column {c + 1}: {fields[c]!r} is not a number ({'xyz'[j]} expected)")
            if math.isinf(v) or (v != v and not allow_nan):
                raise ValueError(f"{path}: line {i + 1}, column {c + 1}: {fields[c]!r}: coordinates must be finite (no NaN or inf)")
            out[k, j] = v
    return out
