"""A batch's ``reason`` column, made column-wise: one template per status filled by pyarrow compute,
and the rare notes of single holes (a reading out of range, a gross reading, a hole not in the
table) kept sparse, by row. A log where every hole fails makes its million reasons without a
Python loop over them (a formatted string per row cost 3 s of CPU per million holes).

The numbers read as Python's ``f"{x:.4f}"`` writes them, byte for byte: the rounded value's integer
and fraction cast to text by pyarrow; the few values within a rounding error of a tie, and negative
ones, go through Python's own formatting.
"""

from __future__ import annotations

import numpy as np

from metrology.measure.batch import CODE, Status

__all__ = ["fixed", "verdict_reasons", "reason_column"]


def fixed(x, digits: int = 4):
    """pyarrow StringArray: ``f"{v:.{digits}f}"`` of each finite ``x (m,)``, column-wise."""
    import pyarrow as pa
    import pyarrow.compute as pc

    x = np.asarray(x, float)
    s = 10 ** digits
    y = x * s
    r = np.rint(y)
    tie = np.abs(np.abs(y - np.floor(y)) - 0.5) < 1e-6  # a rounding error from a tie: Python decides
    slow = np.flatnonzero(tie | np.signbit(x) | ~(x >= 0) | (y > 2 ** 52))
    r = r.astype(np.int64)
    whole = pc.cast(pa.array(r // s), pa.string())
    frac = pc.utf8_lpad(pc.cast(pa.array(r % s), pa.string()), digits, "0")
    out = pc.binary_join_element_wise(whole, frac, ".")
    if slow.size:
        mask = np.zeros(len(x), bool)
        mask[slow] = True
        out = pc.replace_with_mask(out, pa.array(mask), pa.array([f"{v:.{digits}f}" for v in x[slow]], pa.string()))
    return out


def verdict_reasons(code, judge_after, judged, judged_u, tolerance):
    """pyarrow StringArray (N,): why each failing or undecided hole is so (ISO 14253-1, the angle and U95
    in deg to 4 places); "" for the others.

    Parameters
    ----------
    code : (N,) int8, each hole's status code; judge_after : (N,) bool, judged after the adjustment
    judged, judged_u : (N,) float, rad, the angle judged and its U95; tolerance : float, rad
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    N = len(code)
    out = pa.array(np.full(N, ""), pa.string())  # (a fresh array of "" per batch: cheap beside the texts)
    tol = f"{np.degrees(tolerance):g}"
    for status, (mid, end) in ((Status.FAILS, (" deg - U95 ", f" deg > tolerance {tol} deg")),
                               (Status.UNDECIDED, (" deg +- U95 ", f" deg straddles the tolerance {tol} deg"))):
        mask = code == CODE[status]
        if not mask.any():
            continue
        every = bool(mask.all())  # every hole one status (a log all failing): no gathers, no scatter
        rows = slice(None) if every else np.flatnonzero(mask)
        after = judge_after[rows]
        where = ("after the adjustment: angle " if after.all() else "as measured: angle " if not after.any() else
                 pc.if_else(pa.array(after), "after the adjustment: angle ", "as measured: angle "))
        text = pc.binary_join_element_wise(where, fixed(np.degrees(judged[rows])), mid, fixed(np.degrees(judged_u[rows])),
                                           end, "")
        out = text if every else pc.replace_with_mask(out, pa.array(mask), text)
    return out


def reason_column(verdict, notes: dict):
    """pyarrow StringArray: the ``verdict`` reasons (:func:`verdict_reasons`) with the sparse ``notes``
    (row -> text) before them (``note; verdict``, or the note alone)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if not notes:
        return verdict
    rows = np.fromiter(sorted(notes), np.int64, len(notes))
    mask = np.zeros(len(verdict), bool)
    mask[rows] = True
    tail = verdict.take(pa.array(rows)).to_pylist()
    text = [notes[r] + ("; " + t if t else "") for r, t in zip(rows.tolist(), tail)]
    return pc.replace_with_mask(verdict, pa.array(mask), pa.array(text, pa.string()))
