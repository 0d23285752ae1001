"""A batch's ``reason`` column, made column-wise: one fixed text per cause, chosen by each hole's status
and whether it was judged after the adjustment, with the rare notes of single holes (a reading out of
range, a gross reading, a hole not in the table) kept sparse, by row.

The verdict's texts carry no number: the angle judged, its U95 and the tolerance are their own columns
and the summary's; a text per cause is a handful of distinct values, which the Parquet writer keeps as a
dictionary (a reason formatted with each hole's figures cost 0.25 s of CPU per million failing holes to
make and as much to write, with no dictionary possible). A hole with nothing to say (it conforms) has "".
"""

from __future__ import annotations

import numpy as np

from metrology.io.arrays import strings
from metrology.measure.batch import CODE, Status

__all__ = ["VERDICT_TEXTS", "EDGE_TEXT", "verdict_reasons", "reason_column"]

#: why a failing or undecided hole is so (ISO 14253-1), as measured (the log has no after-readings for it) and
#: after the attitude adjustment: ``VERDICT_TEXTS[status][after]``
VERDICT_TEXTS = {
    Status.FAILS: ("as measured: angle - U95 > tolerance", "after the adjustment: angle - U95 > tolerance"),
    Status.UNDECIDED: ("as measured: angle +- U95 straddles the tolerance",
                       "after the adjustment: angle +- U95 straddles the tolerance"),
}
#: what a failing or undecided hole's text adds where its U95 covers one sensor's offset (rule 2b,
#: :data:`metrology.measure.rules.EDGE_SIGMAS`)
EDGE_TEXT = (" (U95 covers one sensor's offset: the redundant reading's misfit is beyond the noise, within the "
             "radius bound, and one reading offset by a burr or a chip gives it as well as the panel's curvature)")
#: the column's distinct verdict values: "" (nothing to say), each text of :data:`VERDICT_TEXTS`, then each with
#: :data:`EDGE_TEXT`
_VALUES = ("", *(t for pair in VERDICT_TEXTS.values() for t in pair),
           *(t + EDGE_TEXT for pair in VERDICT_TEXTS.values() for t in pair))


def verdict_reasons(code, judge_after, edge=None, noted=None):
    """pyarrow StringArray (N,): each failing or undecided hole's :data:`VERDICT_TEXTS`; "" for the others.

    Parameters
    ----------
    code : (N,) int8, each hole's status code; judge_after : (N,) bool, judged after the adjustment
    edge : (N,) bool or None, the judged U95 covers one sensor's offset (rule 2b): :data:`EDGE_TEXT` added
    noted : (N,) bool or None, holes whose note says why they have their status, which no verdict text names
        (rule 3b: undecided though angle - U95 > tolerance): "" here, the note alone in :func:`reason_column`
    """
    import pyarrow as pa

    index = np.zeros(len(code), np.int8)  # "" (values[0]) where the status has no text
    for k, status in enumerate(VERDICT_TEXTS):
        mask = code == CODE[status]
        index[mask] = 1 + 2 * k + judge_after[mask]
    if edge is not None:
        index[edge & (index > 0)] += 2 * len(VERDICT_TEXTS)
    if noted is not None:
        index[noted] = 0
    return strings(_VALUES).take(pa.Array.from_buffers(pa.int8(), len(index), [None, pa.py_buffer(index)]))


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
