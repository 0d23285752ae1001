"""Each row's local surface put into the TCS, with the panel known (``measure --panel``/``--points``):
through the robot's commanded pose where the log states it (the head's spin known), else by the cell's
convention (TCS x, y near the panel's x, y; the spin within ``+-spin``, :mod:`metrology.measure.spin`).

:func:`place` is what :func:`metrology.measure.holes.measure_batch` knows of a batch's surfaces before it
fits a normal: a :class:`Placed`, one array per row.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from metrology.io.holelog_schema import table_key
from metrology.measure.beyond import Beyond
from metrology.measure.normals import drill_axis
from metrology.measure.pose import read_pose

if TYPE_CHECKING:
    from metrology.core.layout import SensorLayout
    from metrology.measure.panel import HoleSurfaces

__all__ = ["Placed", "place"]


@dataclass(frozen=True)
class Placed:
    """A batch's local surfaces in the TCS.

    Attributes
    ----------
    key : str, the log's column that names each row's hole in the table (``point_id``, else ``hole_id``)
    table_row : (N,) int, each row's hole in the table (-1: not in it)
    shape : (N, 3, 3) float, 1/mm, TCS, the local surface's shape operator (0 where not in the table)
    u_shape : (N,) float, 1/mm, its stated uncertainty
    spin : (N,) float, rad, the head's spin about the drill axis is within +-spin (0 where the pose gives it)
    higher : Beyond or None, the CAD beyond second order at the spots, and the head's rotation
    convention : (N,) bool, rows whose shape rests on the cell's convention (no pose)
    stated : bool, that convention was stated (``--spin-deg``)
    pose : tuple or None, the log's commanded pose (:func:`metrology.measure.pose.read_pose`)
    """

    key: str
    table_row: np.ndarray
    shape: np.ndarray
    u_shape: np.ndarray
    spin: np.ndarray
    higher: Beyond | None
    convention: np.ndarray
    stated: bool
    pose: tuple | None

    def after(self, turn) -> "Placed":
        """The surfaces after the adjustment: the head keeps the spin ``turn`` (N,) found before it
        (:class:`metrology.measure.surface.PanelTerms`)."""
        h = self.higher
        return self if h is None else replace(self, higher=Beyond(h.axes, h.higher, None, turn, h.u_height))


def place(surf: "HoleSurfaces", table, layout: "SensorLayout") -> Placed:
    """The local surface of every row of ``table`` (a batch of the log) in the TCS of ``layout``'s head."""
    import pyarrow as pa

    N = table.num_rows
    # the table's own id: ``point_id`` where the log has it (a hole table drilled more than once
    # gives each pass its own hole_id, ``ID#k``: metrology/sim/forward/log_write.py), else hole_id
    key = table_key(table.column_names)
    table_row = surf.rows(table.column(key).cast(pa.string()))
    have = table_row >= 0
    shape, u_shape = np.zeros((N, 3, 3)), np.zeros(N)
    spin, convention = np.full(N, float(surf.spin)), np.zeros(N, bool)
    higher = None
    pose = read_pose(table)  # the robot's commanded tcs2panel where the log states it
    if not have.any():
        return Placed(key, table_row, shape, u_shape, spin, higher, convention, surf.spin_stated, pose)
    axis = drill_axis(layout)[2]
    posed = np.zeros(N, bool) if pose is None else np.isfinite(pose[0][:, 0, 0])  # a row NaN or finite
    sel = (have & posed, have & ~posed)
    convention = sel[1]
    whole = [slice(None) if m.all() else m for m in sel]  # every row one way (the usual): no gathers
    if sel[0].any():  # the pose gives the spin: no doubt about it left in U95
        w = whole[0]
        if isinstance(w, slice):  # every row: the array itself, no copy
            shape = surf.shape_pose(table_row, pose[0], axis)
        else:
            shape[w] = surf.shape_pose(table_row[w], pose[0][w], axis)
        spin[posed] = 0.0
    if sel[1].any():  # the cell's convention (TCS x, y near the panel's x, y; spin within +-spin)
        w = whole[1]
        shape[w] = surf.shape_tcs(table_row[w], axis)
    for k, m in enumerate(sel):  # the CAD beyond second order at the spots (0 where no table row)
        if surf.higher is not None and m.any():
            w = whole[k]
            hx = surf.higher_tcs(table_row[w], axis, pose[0][w] if k == 0 else None)
            if isinstance(w, slice):  # every row: the arrays themselves, no copy
                higher = Beyond(*hx)
            else:
                if higher is None:
                    higher = Beyond(np.zeros((N, 2, 3)), np.zeros((N, surf.higher.shape[1])), np.full((N, 3, 3), np.nan))
                higher.axes[w], higher.higher[w], higher.tcs2panel[w] = hx
    u_shape = surf.u_shape[table_row] if have.all() else np.where(have, surf.u_shape[table_row], 0.0)
    if higher is not None and surf.u_height is not None:  # metrology.measure.remainder
        higher = replace(higher, u_height=np.where(have, surf.u_height[table_row], 0.0))
    return Placed(key, table_row, shape, u_shape, spin, higher, convention, surf.spin_stated, pose)
