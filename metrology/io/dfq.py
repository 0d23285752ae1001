"""Results as a Q-DAS ASCII transfer file (AQDEF, ``.dfq``): what SPC software (qs-STAT and the
many tools that import DFQ) reads.

A DFQ file is lines of K-fields, ``Knnnn/i value`` (``i`` the characteristic's number, from 1). The
fields metro writes, with their meaning in the Q-DAS ASCII transfer format (V12; the field lists
of Q-DAS' own data-format pages and PC-DMIS' "Supported K-Fields"):

========  ====================================  =====================================================
field     Q-DAS meaning                         what metro writes
========  ====================================  =====================================================
K0100     total number of characteristics       the characteristics below
K1001     part number (AN 30)                   the part: the hole table's file stem, or ``holes``
K1002     part description (AN 80)              what was measured
K1082     machine description (AN 40)           the cells' numbers (K0010) and names, when they fit
K2001/i   characteristic number (AN 40)         the hole table's ``hole_id`` (or ``perpendicularity``)
K2002/i   characteristic description (AN 80)    ``perpendicularity <hole_id>``
K2004/i   characteristic type                   0: variable
K2022/i   decimal places                        6
K2043/i   recording device name (string)        the head, with its calibration's full SHA-256
K2101/i   nominal value                         0
K2111/i   upper specification limit             the tolerance (deg)
K2142/i   unit                                  deg
K0001/i   measured value                        the hole's judged angle, deg (after the adjustment
                                                where measured, else before: as ``--qif``)
K0002/i   attribute                             0 valid; 255 placeholder: the hole not measured
                                                (its K0001 is 0 and is not shown or used)
K0004/i   date/time                             the hole's time, UTC, ``YYYY-MM-DD/HH:MM:SS``
K0010/i   machine number (I10)                  the cell's number (cells numbered in order of
                                                first appearance; names in K1082)
K0012/i   gauge number (I10)                    the first 32 bits of the calibration's SHA-256 as an
                                                integer (the field is numeric; the full hash: K2043)
========  ====================================  =====================================================

Dates: ``YYYY-MM-DD/HH:MM:SS`` is one of the format's notations (year-month-day, ``/``, time) and
cannot be read day-for-month, which ``DD.MM.YYYY`` can by a reader that guesses (aqdefreader
reads 05.02.2024 as 2 May). Values: the shortest decimal that reads back as the same float, never
with an exponent.

Streamed and atomic: value lines go, batch by batch, to a spool file beside the target; closing
writes the header (which needs the characteristics met) and the spool into a temporary file renamed
onto the target (:mod:`metrology.io.atomic`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Characteristic", "DfqWriter", "DfqHoles", "check_dfq_path", "write_calibration_dfq", "PLACEHOLDER",
           "gauge_number", "dfq_time"]

#: K0002's attribute for a value not shown and not used: a hole not measured
PLACEHOLDER = 255
_DECIMALS = 6


def check_dfq_path(path, what: str = "--dfq") -> Path:
    """Refuse, before any work, a DFQ path that cannot be written (ValueError, one line)."""
    from metrology.io.atomic import check_output_file

    return check_output_file(path, what, {".dfq"})


def gauge_number(sha256: str) -> int:
    """K0012's number for a calibration: its SHA-256's first 32 bits (<= 4294967295, fits I10)."""
    return int(sha256[:8], 16)


def _clean(text: str, length: int) -> str:
    """A K-field's text: one line, at most ``length`` characters (the field's length)."""
    return " ".join(str(text).split())[:length]


def _number(x: float) -> str:
    """The shortest decimal that reads back as ``x``, without an exponent."""
    return np.format_float_positional(float(x), unique=True, trim="-")


def _numbers(x: np.ndarray):
    """(N,) float -> pyarrow strings, each :func:`_number` (pyarrow's shortest form, its exponents redone)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    s = pa.array(np.where(np.isfinite(x), x, 0.0)).cast(pa.string())
    exp = np.asarray(pc.match_substring(s, "e").to_numpy(zero_copy_only=False), bool)
    if exp.any():
        py = s.to_pylist()
        for k in np.flatnonzero(exp):
            py[k] = _number(x[k])
        s = pa.array(py, pa.string())
    return s


def dfq_time(seconds: np.ndarray):
    """(N,) float seconds since 1970-01-01 UTC -> pyarrow strings ``YYYY-MM-DD/HH:MM:SS`` (UTC)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    ts = pa.array(np.floor(seconds).astype(np.int64)).cast(pa.timestamp("s", tz="UTC"))
    return pc.strftime(ts, format="%Y-%m-%d/%H:%M:%S", locale="C")


@dataclass(frozen=True)
class Characteristic:
    """One K2xxx block: ``number`` (K2001), ``description`` (K2002), ``unit`` (K2142), ``nominal``
    (K2101), ``upper``/``lower`` specification limits (K2111/K2110; None: none), ``device`` (K2043)."""

    number: str
    description: str
    unit: str
    nominal: float | None = None
    upper: float | None = None
    lower: float | None = None
    device: str = ""

    def lines(self, i: int) -> str:
        f = [(2001, _clean(self.number, 40)), (2002, _clean(self.description, 80)), (2004, "0"),
             (2022, str(_DECIMALS))]
        if self.device:
            f.append((2043, _clean(self.device, 255)))
        f += [(k, _number(v)) for k, v in ((2101, self.nominal), (2110, self.lower), (2111, self.upper)) if v is not None]
        f.append((2142, _clean(self.unit, 20)))
        return "".join(f"K{k:04d}/{i} {v}\n" for k, v in f)


class DfqWriter:
    """A DFQ file written as values come (a context manager; the file appears when the block ends
    without error). ``part``: K1xxx fields {number: text}; characteristics may be added while values
    come (their block is written at the end, before the values)."""

    def __init__(self, path, part: dict, what: str = "--dfq"):
        self.path = Path(path)
        self.part = dict(part)
        self.what = what
        self.chars: list[Characteristic] = []
        self.n = 0
        self._dir = None

    def __enter__(self):
        self._dir = tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.resolve().parent)
        self._spool = open(os.path.join(self._dir, "values"), "wb")
        return self

    def add(self, char: Characteristic) -> int:
        """Add a characteristic; its number ``i`` (from 1)."""
        self.chars.append(char)
        return len(self.chars)

    def values(self, index, value, attribute, when, machine, gauge: int) -> None:
        """Value lines: ``index`` (N,) int characteristic numbers, ``value`` (N,) float, ``attribute``
        (N,) int K0002, ``when`` (N,) pyarrow strings K0004, ``machine`` (N,) int K0010, ``gauge`` K0012."""
        import pyarrow as pa
        import pyarrow.compute as pc

        m = len(index)
        if m == 0:
            return
        i = pa.array(np.asarray(index, np.int64)).cast(pa.string())
        rows = pc.binary_join_element_wise(
            "K0001/", i, " ", _numbers(np.asarray(value, float)), "\nK0002/", i, " ",
            pa.array(np.asarray(attribute, np.int64)).cast(pa.string()), "\nK0004/", i, " ", when, "\nK0010/", i, " ",
            pa.array(np.asarray(machine, np.int64)).cast(pa.string()), "\nK0012/", i, f" {int(gauge)}\n", "")
        for chunk in (rows.chunks if isinstance(rows, pa.ChunkedArray) else [rows]):
            self._spool.write("".join(chunk.to_pylist()).encode())
        self.n += m

    def __exit__(self, exc_type, exc, tb):
        from metrology.io.atomic import atomic_path

        try:
            self._spool.close()
            if exc_type is None:
                if self.n == 0:
                    raise ValueError(f"{self.what} {self.path}: no values, nothing to write")
                lengths = {1001: 30, 1002: 80, 1082: 40}
                head = f"K0100 {len(self.chars)}\n" + "".join(
                    f"K{k:04d} {_clean(v, lengths.get(k, 80))}\n" for k, v in sorted(self.part.items()))
                head += "".join(c.lines(i) for i, c in enumerate(self.chars, start=1))
                with atomic_path(self.path) as tmp, open(tmp, "wb") as out:
                    out.write(head.encode("utf-8"))
                    with open(self._spool.name, "rb") as fh:
                        shutil.copyfileobj(fh, out, 1 << 22)
        finally:
            shutil.rmtree(self._dir, ignore_errors=True)
        return False


class DfqHoles:
    """``metro measure --dfq``: per-hole results (tables with ``hole_id``, ``angle_deg``,
    ``angle_after_deg``, ``status``, ``time``, and ``cell`` if the log has one) as a DFQ file: one
    characteristic per hole of the hole table (``features``, in its order; a hole met that is not in
    it gets its own characteristic after them), or one for the whole log (``features`` None). A hole's
    feature is its ``point_id`` where the log has one (a table drilled more than once), else its ``hole_id``."""

    def __init__(self, path, *, tolerance_deg: float, layout_path, features=None, part: str = "holes",
                 log: str = ""):
        from metrology.io.names import sha256_file

        self.sha256 = sha256_file(layout_path)
        self.gauge = gauge_number(self.sha256)
        self.tolerance_deg = float(tolerance_deg)
        self.device = f"metro normal-sensor head, calibration sha256:{self.sha256}"
        self.cells: dict = {}
        self.index: dict = {}
        self.single = features is None
        self.doc = DfqWriter(path, {1001: part, 1002: f"drilled holes' perpendicularity, metro measure {log}".strip()})
        if self.single:
            self.doc.add(self._char("perpendicularity", "perpendicularity of the drill axis to the surface"))
        else:
            for f in features:
                self._feature(str(f))

    def _char(self, number: str, description: str) -> Characteristic:
        return Characteristic(number, description, "deg", nominal=0.0, upper=self.tolerance_deg, device=self.device)

    def _feature(self, hole_id: str) -> int:
        if hole_id not in self.index:
            self.index[hole_id] = self.doc.add(self._char(hole_id, f"perpendicularity {hole_id}"))
        return self.index[hole_id]

    def __enter__(self):
        self.doc.__enter__()
        return self

    def write(self, table) -> None:
        import pyarrow as pa
        import pyarrow.compute as pc

        from metrology.io.holelog_reader import time_seconds
        from metrology.io.holelog_schema import table_key

        m = table.num_rows
        if m == 0:
            return

        def num(c):
            return table.column(c).to_numpy().astype(float)

        after = num("angle_after_deg")
        angle = np.where(np.isfinite(after), after, num("angle_deg"))
        measured = np.asarray(pc.not_equal(table.column("status"), "not_measured").to_numpy(zero_copy_only=False), bool)
        measured &= np.isfinite(angle)
        attribute = np.where(measured, 0, PLACEHOLDER)
        if self.single:
            index = np.ones(m, np.int64)
        else:
            ids = table.column(table_key(table.column_names)).cast(pa.string()).to_pylist()  # a pass's hole: its point ID
            index = np.fromiter((self._feature(h) for h in ids), np.int64, m)
        if "cell" in table.column_names:
            names = table.column("cell").cast(pa.string()).to_pylist()
            machine = np.fromiter((self.cells.setdefault(c, len(self.cells) + 1) for c in names), np.int64, m)
        else:
            machine = np.ones(m, np.int64)
        when = dfq_time(time_seconds(table.column("time")))
        self.doc.values(index, np.where(measured, angle, 0.0), attribute, when, machine, self.gauge)

    def __exit__(self, exc_type, exc, tb):
        legend = ", ".join(f"{n} {c}" for c, n in self.cells.items())
        if legend and len("cells " + legend) <= 40:
            self.doc.part[1082] = "cells " + legend
        return self.doc.__exit__(exc_type, exc, tb)


def write_calibration_dfq(path, toml_text: str, nominal, when_s: float, part: str = "normal-sensor head") -> None:
    """``metro calibrate --dfq``: the calibrated layout (``toml_text``, the bytes ``--out`` writes: its
    values as the certificate states them, its SHA-256 the gauge) as one DFQ part, atomically: per
    sensor its zero point ``zero_x``/``_y``/``_z`` (mm, TCS) and beam direction ``direction_i``/``_j``/
    ``_k`` (unit vector, TCS), each a characteristic whose nominal is the nominal layout's value (no
    limits: the calibration states, it does not judge), one value each at ``when_s`` (seconds since
    1970 UTC)."""
    import hashlib
    import tomllib

    sha256 = hashlib.sha256(toml_text.encode()).hexdigest()
    sensors = {s["name"]: s for s in tomllib.loads(toml_text)["sensors"]}
    device = f"metro normal-sensor head, calibration sha256:{sha256}"
    with DfqWriter(path, {1001: part, 1002: "calibrated sensor zero points and beam directions, metro calibrate"}) as doc:
        values, idx = [], []
        for j, name in enumerate(nominal.names):
            for what, unit, axes, nom in (("zero", "mm", "xyz", nominal.zero[j]),
                                          ("direction", "1", "ijk", nominal.direction[j])):
                for axis, c, v in zip(axes, nom, sensors[name][what]):
                    idx.append(doc.add(Characteristic(f"{name}.{what}_{axis}", f"sensor {name} {what} {axis} (TCS)",
                                                      unit, nominal=float(c), device=device)))
                    values.append(float(v))
        n = len(idx)
        doc.values(np.array(idx), np.array(values), np.zeros(n, np.int64), dfq_time(np.full(n, float(when_s))),
                   np.ones(n, np.int64), gauge_number(sha256))
