"""The panel a ``metro measure`` run drills: the cell's panel as its layout states it
(:func:`layout_panel`), the head's footprint (:func:`footprint_mm`), and each hole's local surface
from the CAD panel and the hole table, or the table alone (:func:`hole_surfaces`,
:func:`panel_hole_surfaces`). Used by :mod:`metrology.jobs.measure` and
:mod:`metrology.jobs.measure_follow`."""

from __future__ import annotations

import numpy as np

__all__ = ["layout_panel", "footprint_mm", "hole_surfaces", "panel_hole_surfaces"]


def layout_panel(layout_path) -> dict:
    """The cell's panel as its layout file states it: ``[panel]`` with ``file`` (a mesh or STEP) and
    ``points`` (the hole table), paths relative to the layout file; or ``points`` alone; or
    ``radius_mm`` (the smallest radius of the cell's panels, mm). {} when the file has none."""
    import tomllib
    from pathlib import Path

    try:
        with open(layout_path, "rb") as fh:
            table = tomllib.load(fh).get("panel")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return {}  # load_layout names these
    if table is None:
        return {}
    if not isinstance(table, dict) or set(table) - {"file", "points", "radius_mm"}:
        raise ValueError(f"{layout_path}: [panel] takes file, points (paths) and radius_mm, got "
                         f"{sorted(table) if isinstance(table, dict) else table!r}")
    out = {}
    base = Path(layout_path).parent
    for k in ("file", "points"):
        if k in table:
            if not isinstance(table[k], str) or not table[k]:
                raise ValueError(f"{layout_path}: [panel] {k} must be a path, got {table[k]!r}")
            out[k] = base / table[k]
    if "radius_mm" in table:
        r = table["radius_mm"]
        r = float("inf") if r == "inf" else r
        if not isinstance(r, (int, float)) or not r > 0:
            raise ValueError(f"{layout_path}: [panel] radius_mm must be a positive number of mm (or \"inf\"), got {r!r}")
        out["radius_mm"] = float(r)
    return out


def footprint_mm(layout) -> float:
    """The head's footprint radius (mm): the spots' largest distance from the tool axis at mid-range
    readings (at the default stand-off where the range is not stated)."""
    mid = layout.range_mm.mean(1)
    if np.all(np.isfinite(mid)):
        spots = layout.zero + mid[:, None] * layout.direction
        return float(np.max(np.hypot(spots[:, 0], spots[:, 1])))
    from metrology.panel.edges import footprint_radius
    from metrology.panel.head import default_standoff

    return footprint_radius(layout, default_standoff(layout))


def hole_surfaces(layout, panel, points, position_error_mm, form_tolerance_mm, spin_deg):
    """Each hole's local surface (HoleSurfaces) from the panel and the hole table, or the table alone."""
    from metrology.measure.panel import read_hole_table, surfaces_from_table

    for name, v in (("--position-error-mm", position_error_mm), ("--form-tolerance-mm", form_tolerance_mm),
                    ("--spin-deg", spin_deg)):
        if not (np.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {v:g}")
    table = read_hole_table(points)
    foot = footprint_mm(layout)
    if panel is None:
        return surfaces_from_table(table, foot, form_tolerance_mm, float(np.radians(spin_deg)))
    from metrology.io.names import display_name
    from metrology.panel.mesh import load_panel

    return panel_hole_surfaces(load_panel(panel), table, foot, position_error_mm, form_tolerance_mm,
                               float(np.radians(spin_deg)), display=display_name(panel))


def panel_hole_surfaces(panel, table, footprint_mm, position_mm=0.5, form_mm=0.0, spin=0.0, display=None):
    """:class:`metrology.measure.panel.HoleSurfaces` of a hole table on a loaded panel
    (:func:`metrology.panel.holes.panel_surfaces`); ``spin`` rad."""
    from metrology.measure.panel import HoleSurfaces
    from metrology.panel.holes import panel_surfaces

    f = panel_surfaces(panel, table, footprint_mm, position_mm, form_mm, display)
    return HoleSurfaces(table.ids, f["normal"], f["shape"], f["k"], f["u_shape"], f["problem"], f["source"], spin,
                        point=table.point, frame=f["frame"], higher=f["higher"], u_height=f.get("u_height"))
