"""PLY: a strict header parser, a strict ASCII body reader, and the size check of binary bodies.

Why metro parses ASCII PLY itself: Open3D's (RPly's) ASCII reader, on a bad token (``Inf``
in an integer field, ``3.3`` in a ``uchar``, ``abc``) or a short row, prints a message of its
own and still returns the declared number of vertices, the unread ones filled from
uninitialised memory. Here every token is checked against its declared type and range, every
row must hold exactly its declared tokens, every element exactly its declared rows. Lines
after the last element are read past, as RPly and PCL read past them, unless one parses as a
vertex row (then the vertex count may be wrong, and the file is refused). The first problem raises one
``ValueError``: ``<file>: line <n>: <what was found>, expected <what>``.
Why not the ``plyfile`` library: its ASCII path accepts ``Inf``, 1e39 in a ``float`` (as
inf) and rows after the last element, names rows not file lines, and is a Python loop per
row, about 20 times slower than this reader (``benchmarks/bench_cloud_readers.py``, which
also measures this reader against Open3D's ASCII reader).

Header grammar (Paul Bourke's PLY specification, as plyfile reads it): ``ply``; ``format
ascii|binary_little_endian|binary_big_endian 1.0``; any number of ``comment ...`` and
``obj_info ...`` lines; ``element <name> <count>`` followed by its ``property <type> <name>``
or ``property list <count type> <item type> <name>`` lines; ``end_header``. Types: ``char
uchar short ushort int uint float double`` and ``int8 uint8 int16 uint16 int32 uint32
float32 float64``. metro reads the ``vertex`` element's scalar ``x``, ``y``, ``z``.

ASCII values are parsed as float64 from their text (exact to the text, whatever the
declared float width); ``nan`` is accepted in float fields (a missing return in an organized
scan, counted by the caller); ``inf`` and values out of the declared type's range are refused.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: PLY type name -> numpy dtype
PLY_TYPES = {
    "char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
    "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
    "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8",
}
_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
_INT = re.compile(r"[+-]?[0-9]+\Z")
_FLOAT = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?\Z|[+-]?nan\Z", re.IGNORECASE)
_F32_MAX = float(np.finfo(np.float32).max)
#: the dtype of a padding property (PCD's ``_`` fields): any token, skipped unparsed, as PCL does
PAD = "pad"


@dataclass(frozen=True)
class PlyProperty:
    """One property: ``name``, numpy ``dtype`` code, and for a list the ``count_dtype``."""

    name: str
    dtype: str
    count_dtype: str | None = None


@dataclass(frozen=True)
class PlyElement:
    """One element: ``name``, declared ``count``, its ``properties`` and its header ``line``."""

    name: str
    count: int
    properties: tuple
    line: int

    @property
    def row_bytes(self):
        """Bytes per binary row, or ``None`` when a list property makes rows variable."""
        if any(p.count_dtype for p in self.properties):
            return None
        return sum(np.dtype(p.dtype).itemsize for p in self.properties)


@dataclass(frozen=True)
class PlyHeader:
    """A parsed header: ``format``, ``elements``, ``body_offset`` (bytes), ``header_lines``."""

    format: str
    elements: tuple
    body_offset: int
    header_lines: int


def _fail(path, line, found, expected):
    raise ValueError(f"{path}: line {line}: {found}, expected {expected}")


def read_ply_header(path) -> PlyHeader:
    """Parse and check a PLY header; the vertex element must have scalar x, y, z."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    lines, pos, n = [], 0, 0
    while True:
        nl = head.find(b"\n", pos)
        if nl < 0:
            if len(head) >= 1 << 16:
                raise ValueError(f"{path}: no end_header in the first 64 KiB, expected a PLY header")
            raw, pos = head[pos:], len(head)
            if raw:
                lines.append(raw)
            break
        raw, pos = head[pos:nl], nl + 1
        lines.append(raw)
        if raw.rstrip(b"\r").split() == [b"end_header"] or raw.startswith(b"end_header"):
            break
    fmt, elements, ended = None, [], False
    for n, raw in enumerate(lines, 1):
        text = raw.rstrip(b"\r").decode("latin-1")
        t = text.split()
        if n == 1:
            if t != ["ply"] or text.strip() != "ply":
                raise ValueError(f"{path}: not a PLY file (line 1: {text[:40]!r}, expected 'ply')")
            continue
        if not t:
            _fail(path, n, "a blank line", "a header keyword")
        key = t[0]
        if key in ("comment", "obj_info"):
            continue
        if key == "format":
            if fmt is not None or elements:
                _fail(path, n, repr(text), "one 'format' line before the elements")
            if len(t) != 3 or t[1] not in _FORMATS or t[2] not in ("1.0", "1"):
                _fail(path, n, repr(text), "'format ascii|binary_little_endian|binary_big_endian 1.0'")
            fmt = t[1]
        elif key == "element":
            if fmt is None:
                _fail(path, n, repr(text), "'format ...' before the first element")
            if len(t) != 3 or not re.fullmatch(r"[0-9]+", t[2]):
                _fail(path, n, repr(text), "'element <name> <count>' with a count >= 0")
            if any(e[0] == t[1] for e in elements):
                _fail(path, n, f"a second element {t[1]!r}", "each element declared once")
            elements.append([t[1], int(t[2]), [], n])
        elif key == "property":
            if not elements:
                _fail(path, n, repr(text), "'element ...' before its properties")
            if len(t) == 3 and t[1] in PLY_TYPES:
                prop = PlyProperty(t[2], PLY_TYPES[t[1]])
            elif len(t) == 5 and t[1] == "list" and t[2] in PLY_TYPES and t[3] in PLY_TYPES and PLY_TYPES[t[2]][0] in "iu":
                prop = PlyProperty(t[4], PLY_TYPES[t[3]], PLY_TYPES[t[2]])
            else:
                _fail(path, n, repr(text), "'property <type> <name>' or 'property list <int type> <type> <name>'")
            if any(p.name == prop.name for p in elements[-1][2]):
                _fail(path, n, f"a second property {prop.name!r}", "each property of an element declared once")
            elements[-1][2].append(prop)
        elif key == "end_header":
            if t != ["end_header"]:
                _fail(path, n, repr(text), "'end_header' alone")
            if fmt is None:
                _fail(path, n, "'end_header' without a format line", "'format ...'")
            ended = True
            break
        else:
            _fail(path, n, repr(text), "a header keyword (format, element, property, comment, obj_info, end_header)")
    if not ended:
        _fail(path, len(lines) + 1, "the end of the file", "'end_header'")
    header = PlyHeader(fmt, tuple(PlyElement(e[0], e[1], tuple(e[2]), e[3]) for e in elements), pos, n)
    vertex = vertex_element(header)
    if vertex is None:
        raise ValueError(f"{path}: the PLY header declares no vertex element, expected 'element vertex <count>'")
    scalar = {p.name for p in vertex.properties if p.count_dtype is None}
    if not {"x", "y", "z"} <= scalar:
        found = ", ".join(p.name for p in vertex.properties) or "no properties"
        _fail(path, vertex.line, f"element vertex with {found}", "scalar properties x, y, z")
    return header


def vertex_element(header: PlyHeader):
    """The ``vertex`` element of ``header``, or ``None``."""
    return next((e for e in header.elements if e.name == "vertex"), None)


def _walk_rows(path, data, pos, size, e, order):
    """Byte offset after element ``e`` (rows with lists) starting at ``pos``; raise if the
    file ends inside it. Rows of one list property all of the first row's length (a
    triangle mesh's faces) are checked at once; others one by one."""
    if len(e.properties) == 1 and e.count:
        p = e.properties[0]
        c = np.dtype(order + p.count_dtype)
        if pos + c.itemsize <= size:
            m = int(np.frombuffer(data, c, 1, pos)[0])
            row = c.itemsize + m * np.dtype(p.dtype).itemsize
            if m >= 0 and pos + e.count * row <= size:
                block = np.frombuffer(data, np.uint8, e.count * row, pos).reshape(e.count, row)[:, :c.itemsize]
                if (np.ascontiguousarray(block).view(c).ravel() == m).all():
                    return pos + e.count * row
    for r in range(e.count):
        for p in e.properties:
            if p.count_dtype is not None:
                c = np.dtype(order + p.count_dtype)
                if pos + c.itemsize > size:
                    raise ValueError(f"{path}: truncated: the file ends in row {r + 1} of element {e.name!r} "
                                     f"(the count of list {p.name!r}), expected {e.count} rows")
                m = int(np.frombuffer(data, c, 1, pos)[0])
                if m < 0:
                    raise ValueError(f"{path}: row {r + 1} of element {e.name!r}: list {p.name!r} of {m} items, expected a count >= 0")
                pos += c.itemsize + m * np.dtype(p.dtype).itemsize
            else:
                pos += np.dtype(p.dtype).itemsize
            if pos > size:
                raise ValueError(f"{path}: truncated: the file ends in row {r + 1} of element {e.name!r} "
                                 f"(property {p.name!r}), expected {e.count} rows")
    return pos


def check_binary_size(path, header: PlyHeader) -> None:
    """Refuse a binary body shorter or longer than its declared elements: RPly fills
    missing vertices from uninitialised memory. Elements with list properties are walked
    (their row lengths are in the data)."""
    size = Path(path).stat().st_size - header.body_offset
    order = "<" if header.format == "binary_little_endian" else ">"
    data, pos = None, 0
    for e in header.elements:
        if e.row_bytes is not None:
            if e.name == "vertex":
                have = max(size - pos, 0) // e.row_bytes if e.row_bytes else e.count
                if have < e.count:
                    raise ValueError(f"{path}: truncated: the header declares {e.count} vertices, the file holds {have}")
            pos += e.count * e.row_bytes
            if pos > size:
                raise ValueError(f"{path}: truncated: the file ends in element {e.name!r}, "
                                 f"expected {e.count} rows of {e.row_bytes} bytes")
        else:
            if data is None:  # mapped, not read: a mesh's face list may be large
                data = np.memmap(path, np.uint8, "r", offset=header.body_offset) if size else b""
            pos = _walk_rows(path, data, pos, size, e, order)
    if size != pos:
        raise ValueError(f"{path}: {size - pos} byte(s) after the last element: the header declares {pos} bytes of data "
                         f"({', '.join(f'{e.count} {e.name}' for e in header.elements)}), the file holds {size}")


_READ_CHUNK = 1 << 20


def read_binary_vertices(path, header: PlyHeader):
    """x, y, z of a binary PLY's vertex element (scalar properties only) as ``(n, 3) float``.

    The body's size must have been checked (:func:`check_binary_size`). Rows are read in
    chunks of ``_READ_CHUNK``: memory is the output plus one chunk, whatever the row layout.
    """
    order = "<" if header.format == "binary_little_endian" else ">"
    vertex = vertex_element(header)
    offset = header.body_offset
    for e in header.elements:
        if e is vertex:
            break
        if e.row_bytes is not None:
            offset += e.count * e.row_bytes
        else:
            data = np.memmap(path, np.uint8, "r", offset=header.body_offset)
            offset = header.body_offset + _walk_rows(path, data, offset - header.body_offset, len(data), e, order)
            del data
    names = [p.name for p in vertex.properties]
    row = np.dtype([(p.name, order + p.dtype) for p in vertex.properties])
    n = vertex.count
    out = np.empty((n, 3))
    with open(path, "rb") as fh:
        fh.seek(offset)
        if names == ["x", "y", "z"] and all(p.dtype == "f8" for p in vertex.properties):
            raw = out.reshape(-1).view(np.uint8)
            got = fh.readinto(raw)
            if got != raw.nbytes:
                raise ValueError(f"{path}: truncated: the header declares {n} vertices, the file holds {got // 24}")
            if np.dtype(order + "f8") != np.dtype("=f8"):
                out.byteswap(inplace=True)
            return out
        buf = np.empty(min(n, _READ_CHUNK), dtype=row)
        for a in range(0, n, len(buf)):
            part = buf[: min(len(buf), n - a)]
            got = fh.readinto(part.view(np.uint8))
            if got != part.nbytes:
                raise ValueError(f"{path}: truncated: the header declares {n} vertices, the file holds {a + got // row.itemsize}")
            for j, axis in enumerate("xyz"):
                out[a : a + len(part), j] = part[axis]
    return out


def body_lines(path, offset):
    """The lines of the file from byte ``offset`` (``\\n``, ``\\r\\n`` or ``\\r`` endings)."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        text = fh.read().decode("latin-1")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return lines


def _check_token(path, lineno, col, prop, tok, dtype):
    """Parse one token as ``dtype``; raise naming the line, column and value when it is not one."""
    if dtype == PAD:
        return math.nan
    kind = np.dtype(dtype)
    where = f"{path}: line {lineno}, column {col}: {tok!r}"
    what = f"(property {prop.name!r})"
    if kind.kind in "iu":
        if not _INT.match(tok):
            raise ValueError(f"{where} is not an integer, expected {kind.name} {what}")
        v = int(tok)
        info = np.iinfo(kind)
        if not info.min <= v <= info.max:
            raise ValueError(f"{where} is out of range, expected {kind.name} in [{info.min}, {info.max}] {what}")
        return v
    if not _FLOAT.match(tok):
        raise ValueError(f"{where} is not a number, expected {kind.name} (nan allowed, inf not) {what}")
    v = float(tok)
    limit = _F32_MAX if kind.itemsize == 4 else float(np.finfo(np.float64).max)
    if not abs(v) <= limit and v == v:
        raise ValueError(f"{where} is out of range, expected a finite {kind.name} {what}")
    return v


def _parse_rows_slow(path, lines, first, element, first_line_no):
    """Parse ``element``'s rows token by token; raise on the first problem. Returns the
    (count, k) float array of its scalar properties."""
    scalars = [p for p in element.properties if p.count_dtype is None]
    out = np.empty((element.count, len(scalars)))
    for r in range(element.count):
        lineno = first_line_no + first + r
        toks = lines[first + r].split()
        k, j = 0, 0
        for prop in element.properties:
            if prop.count_dtype is not None:
                if k >= len(toks):
                    _fail(path, lineno, f"{len(toks)} value(s), the row ends before list {prop.name!r}",
                          f"a count ({np.dtype(prop.count_dtype).name}) then that many values")
                m = _check_token(path, lineno, k + 1, prop, toks[k], prop.count_dtype)
                k += 1
                if k + m > len(toks):
                    _fail(path, lineno, f"list {prop.name!r} of {m} with {len(toks) - k} value(s) left on the row",
                          f"{m} values")
                for c in range(k, k + m):
                    _check_token(path, lineno, c + 1, prop, toks[c], prop.dtype)
                k += m
                continue
            if k >= len(toks):
                _fail(path, lineno, f"{len(toks)} value(s), the row ends before property {prop.name!r}",
                      f"one value per property ({', '.join(p.name for p in element.properties)})")
            out[r, j] = _check_token(path, lineno, k + 1, prop, toks[k], prop.dtype)
            k += 1
            j += 1
        if k != len(toks):
            _fail(path, lineno, f"{len(toks)} values ({' '.join(toks[k:k + 3])!r} left over)",
                  f"{k} (one per property of element {element.name!r})")
    return out


def _parse_rows_fast(lines, first, element):
    """numpy's C parser over a scalar-only element: ``None`` on any doubt (the slow path decides)."""
    props = element.properties
    # every column as float64, integers checked below: numpy < 2 reads '3.3', 'Inf' or '256'
    # into a uint8 field without a word, so its integer parsing cannot be the check
    dtype = [(f"p{i}", "U64" if p.dtype == PAD else "f8") for i, p in enumerate(props)]
    block = lines[first:first + element.count]
    try:
        rec = np.loadtxt(block, dtype=dtype, comments=None, ndmin=1)
    except ValueError:
        return None
    if len(rec) != element.count:  # numpy skips blank lines
        return None
    out = np.empty((element.count, len(props)))
    for i, p in enumerate(props):
        if p.dtype == PAD:
            out[:, i] = np.nan
            continue
        col = rec[f"p{i}"]
        kind = np.dtype(p.dtype)
        if kind.kind == "f":
            limit = _F32_MAX if kind.itemsize == 4 else np.inf
            if np.any(np.abs(col) > limit) or np.isinf(col).any():
                return None
        else:  # an integer: finite, whole, inside the type's range (else the slow path names it)
            info = np.iinfo(kind)
            if not (np.all(np.isfinite(col)) and np.all(col == np.round(col))
                    and np.all(col >= info.min) and np.all(col <= info.max)):
                return None
        out[:, i] = col
    return out


def parse_rows(path, lines, start, element, first_line_no):
    """Check and parse ``element.count`` rows of ``lines`` from index ``start``; line numbers
    in messages count from ``first_line_no`` (the file line of ``lines[0]``). Returns the
    ``(count, k) float`` values of the element's k scalar properties."""
    if element.count == 0:  # nothing to parse (and numpy's loadtxt would warn of "no data")
        return np.empty((0, sum(p.count_dtype is None for p in element.properties)))
    values = None
    if all(p.count_dtype is None for p in element.properties):
        values = _parse_rows_fast(lines, start, element)
    if values is None:
        values = _parse_rows_slow(path, lines, start, element, first_line_no)
    return values


def _could_be_row(path, line, element) -> bool:
    """Whether ``line`` parses as one row of ``element`` (every token of its declared type)."""
    one = PlyElement(element.name, 1, element.properties, element.line)
    try:
        _parse_rows_slow(path, [line], 0, one, 1)
    except ValueError:
        return False
    return True


def read_ascii_ply(path, header: PlyHeader):
    """The vertex element's x, y, z of an ASCII PLY, and the file lines ignored after the last element.

    Returns
    -------
    xyz : (n, 3) float, file units
        NaN kept.
    ignored : tuple of int
        File line numbers (1-based) of non-blank lines after the last element. They are
        read past, as RPly (Open3D) and PCL do (RPly's own ``etc/input.ply`` has a second face
        row under ``element face 1``; PCL's ``CommentAtTheEnd`` test a ``comment hi`` line),
        only when none of them parses as a vertex row: a line that does may be a vertex the
        header's count left out, and the file is refused.
    """
    lines = body_lines(path, header.body_offset)
    first_line_no = header.header_lines + 1
    start, xyz = 0, None
    for element in header.elements:
        if start + element.count > len(lines):
            lineno = first_line_no + len(lines)
            _fail(path, lineno, f"the end of the file after {len(lines) - start} row(s) of element {element.name!r}",
                  f"{element.count} rows")
        values = parse_rows(path, lines, start, element, first_line_no)
        if element.name == "vertex":
            names = [p.name for p in element.properties if p.count_dtype is None]
            xyz = values[:, [names.index(a) for a in "xyz"]]
        start += element.count
    ignored = []
    vertex = vertex_element(header)
    for i in range(start, len(lines)):
        if not lines[i].strip():
            continue
        if _could_be_row(path, lines[i], vertex):
            last = header.elements[-1]
            _fail(path, first_line_no + i, f"{lines[i].strip()[:40]!r} after the last element ({last.count} {last.name}),"
                  f" a row of element 'vertex' ({vertex.count} declared)", "the end of the file")
        ignored.append(first_line_no + i)
    return xyz, tuple(ignored)
