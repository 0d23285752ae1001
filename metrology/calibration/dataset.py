"""A measured data set: tracker export + datum + layout, checked against each other.

This is the one loader behind ``metro calibrate``, ``validate`` and ``diagnose``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metrology.core.observations import Observations
from metrology.io.export import TrackerExport, read_export
from metrology.core.layout import SensorLayout
from metrology.io.layout import load_layout
from metrology.core.plane import Plane

__all__ = ["Dataset", "load_plane", "load_dataset", "MIN_READINGS"]

#: fewest readings per sensor: the five identifiable parameters plus one to see a residual
MIN_READINGS = 6


def load_plane(path):
    """The datum plane from a ``fit-plane --out`` JSON or from a tracker cloud (fitted robustly).

    Returns
    -------
    plane : Plane, tracker frame
    points : (m, 3) float, mm, tracker frame, or None (the inlier cloud, when a cloud was given)
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        return Plane.from_json(path), None
    from metrology.io.clouds import read_cloud
    from metrology.datum import fit_plane_robust

    points = read_cloud(path)
    try:
        fit = fit_plane_robust(points)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return fit.plane, points[fit.inliers(points)]


@dataclass(frozen=True)
class Dataset:
    """Poses, readings, datum and layout of one run, in the layout's sensor order.

    Attributes
    ----------
    export : TrackerExport (columns in ``layout.names`` order)
    layout : SensorLayout (nominal or calibrated)
    plane : Plane, tracker frame
    datum_points : (m, 3) float, mm, tracker frame, or None
    """

    export: TrackerExport
    layout: SensorLayout
    plane: Plane
    datum_points: np.ndarray | None = None

    @property
    def obs(self) -> Observations:
        """The datum in each pose's TCS and the readings."""
        from metrology.core.frames import plane_in_tcs

        normal, offset = plane_in_tcs(self.plane.normal, self.plane.offset, self.export.tcs2tracker_rot,
                                      self.export.tcs2tracker_trans)
        return Observations(normal, offset, self.export.d)

    def select(self, idx) -> "Dataset":
        return Dataset(self.export.select(idx), self.layout, self.plane, self.datum_points)


def check(export: TrackerExport, layout: SensorLayout, source="export") -> TrackerExport:
    """Check an export against a layout; return it with columns in layout order."""
    extra = [n for n in export.names if n not in layout.names]
    missing = [n for n in layout.names if n not in export.names]
    if extra:
        raise ValueError(f"{source}: sensor(s) {', '.join(extra)} not in the layout ({', '.join(layout.names)})")
    if missing:
        raise ValueError(f"{source}: no reading column for layout sensor(s) {', '.join(missing)}")
    export = export.reordered(layout.names)
    lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
    bad = np.isfinite(export.d) & ((export.d < lo) | (export.d > hi))
    if np.any(bad):
        p, i = np.argwhere(bad)[0]
        raise ValueError(
            f"{source}: pose {export.pose_id[p]}: d_{layout.names[i]} = {export.d[p, i]:g} mm outside the "
            f"sensor's range [{lo[i]:g}, {hi[i]:g}] mm ({bad.sum()} reading(s) out of range)"
        )
    counts = np.isfinite(export.d).sum(axis=0)
    if np.any(counts < MIN_READINGS):
        i = int(np.argmin(counts))
        raise ValueError(f"{source}: sensor {layout.names[i]} has {counts[i]} readings, need at least {MIN_READINGS} "
                         "(5 parameters per sensor)")
    return export


def load_dataset(export_path, plane_path, layout_path) -> Dataset:
    """Read and cross-check the three files of a run (errors name the file and the problem)."""
    layout = load_layout(layout_path)
    export = check(read_export(export_path), layout, str(export_path))
    plane, points = load_plane(plane_path)
    return Dataset(export, layout, plane, points)
