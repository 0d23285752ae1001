"""Panels and drilling points shared by the tests of metrology.panel."""

from __future__ import annotations

import math

import numpy as np

from metrology.core.paper import table2_layouts, table6_layouts
from metrology.panel.mesh import Panel
from metrology.panel.points import DrillPoints
from metrology.panel.surfaces import ParametricSurface, panel_mesh

#: the paper's calibrated heads
LAYOUTS = {"table6": table6_layouts()[1], "table2": table2_layouts()[1]}


def make_panel(kind, radius=math.inf, half=80.0, spacing=1.0):
    surf = ParametricSurface(kind, radius)
    return Panel(panel_mesh(surf, half, half, spacing), kind, [], surf)


def drill(surf, rng, m=20, half=30.0):
    xy = rng.uniform(-half, half, (m, 2))
    pts = np.column_stack([xy, surf.height(xy[:, 0], xy[:, 1])])
    return DrillPoints(pts, np.full_like(pts, np.nan), tuple(str(i) for i in range(m)))
