"""The panel a ``metro measure`` run drills: the cell's panel as its layout states it
(:func:`layout_panel`), the head's footprint (:func:`footprint_mm`), and each hole's local surface
from the CAD panel and the hole table, or the table alone (:func:`hole_surfaces`,
:func:`panel_hole_surfaces`). Used by :mod:`metrology.jobs.measure` and
:mod:`metrology.jobs.measure_follow`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["layout_panel", "footprint_mm", "standoff_mm", "read_table_in_mm", "check_units", "hole_surfaces",
           "surfaces_and_units", "panel_hole_surfaces", "check_join", "CadPanel"]


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
    mid = _mid_range(layout)
    if np.all(np.isfinite(mid)):
        spots = layout.zero + mid[:, None] * layout.direction
        return float(np.max(np.hypot(spots[:, 0], spots[:, 1])))
    from metrology.panel.edges import footprint_radius
    from metrology.panel.head import default_standoff

    return footprint_radius(layout, default_standoff(layout))


def _mid_range(layout) -> np.ndarray:
    """Each sensor's mid-range (n,) mm, NaN where its range is not stated (a nominal layout's (-inf, inf): its mean
    would be inf - inf, numpy's "invalid value encountered in reduce" on stderr, issue 51 item 14)."""
    r = np.asarray(layout.range_mm, float)
    ok = np.all(np.isfinite(r), axis=1)
    mid = np.full(len(r), np.nan)
    mid[ok] = r[ok].mean(1)
    return mid


def standoff_mm(layout) -> float:
    """The readings' stand-off (mm): the sensors' mid-range, else the head's default stand-off."""
    mid = _mid_range(layout)
    if np.all(np.isfinite(mid)):
        return float(np.mean(mid))
    from metrology.panel.head import default_standoff

    return float(default_standoff(layout))


def read_table_in_mm(points, units=None):
    """The hole table (:func:`metrology.measure.panel.read_hole_table`), its points scaled to mm from ``units``."""
    import dataclasses

    from metrology.measure.panel import read_hole_table
    from metrology.panel.mesh import UNITS_MM

    if units is not None and units not in UNITS_MM:
        raise ValueError(f"--units {units}: expected one of {', '.join(UNITS_MM)}")
    table = read_hole_table(points)
    if units is not None and UNITS_MM[units] != 1.0:
        table = dataclasses.replace(table, point=table.point * UNITS_MM[units])
    return table


def check_units(layout, panel=None, table=None, panel_path=None, points_path=None, units=None, log=None):
    """Refuse (ValueError, one line) a loaded panel and hole table that do not read as mm against the
    head of ``layout`` (:func:`metrology.io.panel_units.check_panel_units`), with the commanded positions of
    ``log`` (an opened hole log, or None) at their holes."""
    from metrology.io.names import display_name
    from metrology.io.panel_units import check_panel_units, log_positions

    shown = " and ".join(display_name(p) for p in (panel_path, points_path) if p is not None)
    settled = panel is not None and units is None and not str(panel.units).startswith("mm (assumed")
    poses, at = (None, None) if table is None else log_positions(log, table.ids)
    line = check_panel_units(footprint_mm(layout), standoff_mm(layout),
                             panel_extent=None if panel is None else panel.mesh.extents,
                             table_points=None if table is None else table.point, pose_points=poses,
                             names=shown or "the panel", given=units, panel_in_mm=settled, pose_at=at,
                             log_name=getattr(log, "display", "the log"))
    if line is not None:
        raise ValueError(line)


def hole_surfaces(layout, panel, points, position_error_mm, form_tolerance_mm, spin_deg, units=None, log=None):
    """Each hole's local surface (HoleSurfaces) from the panel and the hole table, or the table alone;
    ``units`` (mm, cm, m, in): the unit of the panel file and the table (None: the panel's own, the table mm).
    Refused (ValueError) when the two, with the commanded positions of ``log`` (an opened hole log, or None),
    do not read as mm against the head (:func:`check_units`)."""
    return surfaces_and_units(layout, panel, points, position_error_mm, form_tolerance_mm, spin_deg, units, log)[0]


def surfaces_and_units(layout, panel, points, position_error_mm, form_tolerance_mm, spin_deg, units=None, log=None):
    """``(surfaces, check)``: :func:`hole_surfaces`, and ``check(log)``, :func:`check_units` of the panel and the
    table as loaded here with the commanded positions of a log opened later (``--follow``'s first lines)."""
    from dataclasses import replace
    from functools import partial

    from metrology.measure.panel import TableNormals
    from metrology.measure.spin import DEFAULT_SPIN_DEG

    stated = spin_deg is not None
    spin_deg = spin_deg if stated else DEFAULT_SPIN_DEG
    for name, v in (("--position-error-mm", position_error_mm), ("--form-tolerance-mm", form_tolerance_mm),
                    ("--spin-deg", spin_deg)):
        if not (np.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {v:g}")
    table = read_table_in_mm(points, units)
    foot = footprint_mm(layout)
    if panel is None:
        check = partial(check_units, layout, None, table, None, points, units)
        check(log)
        source = TableNormals()
    else:
        from metrology.io.names import display_name
        from metrology.panel.mesh import load_panel

        loaded = load_panel(panel, units)
        check = partial(check_units, layout, loaded, table, panel, points, units)
        check(log)
        source = CadPanel(loaded, position_error_mm, display_name(panel))
    surfaces = source.surfaces(table, foot, form_tolerance_mm, float(np.radians(spin_deg)))
    return replace(surfaces, spin_stated=stated), check


@dataclass(frozen=True)
class CadPanel:
    """The CAD panel (a mesh, or a STEP file's B-rep faces, as :func:`metrology.panel.mesh.load_panel` loads
    it): a :class:`metrology.measure.panel.SurfaceSource`; ``position_mm`` the drill point's position error."""

    panel: object
    position_mm: float = 0.5
    display: str | None = None

    def surfaces(self, table, footprint_mm: float, form_mm: float, spin: float):
        return panel_hole_surfaces(self.panel, table, footprint_mm, self.position_mm, form_mm, spin, self.display)


def panel_hole_surfaces(panel, table, footprint_mm, position_mm=0.5, form_mm=0.0, spin=0.0, display=None):
    """:class:`metrology.measure.panel.HoleSurfaces` of a hole table on a loaded panel
    (:func:`metrology.panel.holes.panel_surfaces`); ``spin`` rad."""
    from metrology.measure.panel import HoleSurfaces
    from metrology.panel.holes import panel_surfaces

    f = panel_surfaces(panel, table, footprint_mm, position_mm, form_mm, display)
    return HoleSurfaces(table.ids, f["normal"], f["shape"], f["k"], f["u_shape"], f["problem"], f["source"], spin,
                        point=table.point, frame=f["frame"], higher=f["higher"], u_height=f.get("u_height"))


def check_join(log, surfaces, table_display) -> None:
    """Refuse (ValueError, one line) a log none of whose holes is in the hole table: every hole would be
    ``not_measured`` and the outputs say nothing. Reads the join's key column alone (``point_id`` where
    the log has it, else ``hole_id``), partition by partition, and stops at the first hole found."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from metrology.io.holelog_schema import HOLE_ID, table_key

    known = pa.array(surfaces.ids, pa.string())
    rows, first, key = 0, None, HOLE_ID
    for part in log.partitions:
        key = table_key(log.columns(part))
        for col in _key_column(log, part, key):
            col = col.cast(pa.string())
            if len(col) and pc.any(pc.is_in(col, value_set=known)).as_py():
                return
            rows += len(col)
            if first is None and len(col):
                first = col[0].as_py()
    if rows == 0:
        return  # an empty log is named by its reader
    raise ValueError(f"{log.display}: none of its {rows:,} holes is in the hole table {table_display} (joined on "
                     f"{key}: the log's {first!r}, the table's {surfaces.ids[0]!r}, ...): every hole's surface would "
                     f"be unknown; is it this panel's table?")


def _key_column(log, part, key):
    """The partition's ``key`` column in chunks (pyarrow arrays), read alone."""
    import pyarrow as pa

    if part.path.lower().endswith(".csv"):
        import pyarrow.csv as pcsv

        reader = pcsv.open_csv(part.path, read_options=pcsv.ReadOptions(block_size=1 << 22),
                               convert_options=pcsv.ConvertOptions(include_columns=[key],
                                                                   column_types={key: pa.string()}))
        for batch in reader:
            yield batch.column(0)
        return
    import pyarrow.parquet as pq

    if key in part.keys:  # a hive key: the same for every row of the file
        n = pq.ParquetFile(part.path).metadata.num_rows
        yield pa.array([part.keys[key]] * n, pa.string())
        return
    pf = pq.ParquetFile(part.path)
    groups = range(pf.num_row_groups) if part.row_group is None else (part.row_group,)
    for g in groups:
        yield pf.read_row_group(g, columns=[key]).column(0).combine_chunks()
