"""The holes of a hole table as a ``metro measure`` run judged them, for the report's panel map
(:class:`metrology.report.panel_map.PanelMap`): collected from the per-hole results as they are
written (:class:`HoleAngles`, a sink), or read back from a partitioned output's files."""

from __future__ import annotations

import numpy as np

__all__ = ["HoleAngles", "MAP_COLUMNS", "holes_collector", "panel_box"]

#: the per-hole result columns the map reads
MAP_COLUMNS = ("hole_id", "angle_deg", "angle_after_deg", "status")


class HoleAngles:
    """Each table hole's judged angle (deg) and status, its last pass in the log kept; memory of the
    table's size, whatever the log's. ``write(table)`` takes a batch of per-hole results."""

    def __init__(self, surfaces, source: str, point=None, box=None):
        self.surfaces = surfaces
        self.source = source
        self.box = box  # the panel's vertices' corners, mm, panel frame (None: not drawn)
        self.point = surfaces.point if point is None else point  # (m, 3) mm, panel frame
        m = len(surfaces.ids)
        self.angle = np.full(m, np.nan)
        self.status = np.full(m, "", dtype=object)

    def write(self, table) -> None:
        import pyarrow as pa

        from metrology.io.holelog_schema import table_key

        rows = self.surfaces.rows(table.column(table_key(table.column_names)).cast(pa.string()))

        def num(c):
            return table.column(c).to_numpy(zero_copy_only=False).astype(float)

        after = num("angle_after_deg")
        angle = np.where(np.isfinite(after), after, num("angle_deg"))
        status = np.asarray(table.column("status").to_pylist(), dtype=object)
        ok = rows >= 0
        angle = np.where(status == "not_measured", np.nan, angle)
        self.angle[rows[ok]] = angle[ok]  # numpy keeps the last of repeated rows: the last pass
        self.status[rows[ok]] = status[ok]

    def read_output(self, output, log) -> None:
        """Collect from a partitioned output's files (every partition, whoever wrote it)."""
        import pyarrow.parquet as pq

        for part in log.partitions:
            pf = pq.ParquetFile(output.target(part.relative), pre_buffer=False)
            cols = [c for c in (*MAP_COLUMNS, "point_id") if c in pf.schema_arrow.names]
            for g in range(pf.num_row_groups):
                self.write(pf.read_row_group(g, columns=cols, use_threads=False))

    def panel_map(self):
        from metrology.report.panel_map import PanelMap

        return PanelMap(tuple(self.surfaces.ids), np.asarray(self.point, float), self.angle,
                        self.status.astype(str), self.source, self.box)


def holes_collector(surfaces, panel, points, units=None):
    """The collector of the report's panel map (None without a hole table): the table's points from the
    surfaces, or read again (a table alone gives none to its surfaces)."""
    if surfaces is None:
        return None
    from metrology.io.names import display_name
    from metrology.jobs.measure_panel import read_table_in_mm

    point = surfaces.point if surfaces.point is not None else read_table_in_mm(points, units).point
    return HoleAngles(surfaces, display_name(panel if panel is not None else points), point, panel_box(panel, units))


def panel_box(panel, units=None):
    """``(lo, hi)``, (3,) mm, panel frame: a mesh panel's vertices' lowest and highest corner, for the map to draw
    the panel under its holes; None without a panel, or for a STEP file (its tessellation is not redone for a
    figure). Read only when a report is asked for."""
    if panel is None or str(panel).lower().endswith((".step", ".stp")):
        return None
    from metrology.panel.mesh import load_panel

    v = np.asarray(load_panel(panel, units).mesh.vertices, float)
    return v.min(axis=0), v.max(axis=0)
