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

__all__ = ["Dataset", "load_plane", "load_dataset", "drop_no_reading", "MIN_READINGS", "NO_READING"]

#: fewest readings per sensor: the five identifiable parameters plus one to see a residual
MIN_READINGS = 6

#: the PLC's "no reading" code when none is given: a reading of exactly 0 is no reading for
#: every sensor whose stated range does not contain 0 (a triangulation sensor never reads 0)
NO_READING = 0.0


def plane_covariance_from_json(path):
    """The ``covariance`` (4, 4) of ``(A, B, C, D)`` (unitless normal, mm) a ``fit-plane --out``
    JSON keeps, or None when the file has none (the plane is then taken as exact).

    Raises ValueError naming the file when the key is there but is not a finite, symmetric,
    positive semi-definite 4 x 4 matrix."""
    import json

    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    raw = data.get("covariance") if isinstance(data, dict) else None
    if raw is None:
        return None
    try:
        cov = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        cov = np.full((1,), np.nan)
    if cov.shape != (4, 4) or not np.all(np.isfinite(cov)) or np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < \
            -1e-9 * max(float(np.max(np.abs(cov))), 1e-300):
        raise ValueError(f"{path}: 'covariance' must be a finite, positive semi-definite 4 x 4 matrix of "
                         "(A, B, C, D) (as metro fit-plane writes it), or absent")
    return 0.5 * (cov + cov.T)


def load_plane(path, with_cloud=False, with_cov=False):
    """The datum plane from a ``fit-plane --out`` JSON or from a tracker cloud (fitted robustly).

    Returns
    -------
    plane : Plane, tracker frame
    points : (m, 3) float, mm, tracker frame, or None (the inlier cloud, when a cloud was given)
    cloud : (k, 3) float, mm, tracker frame, or None; only ``with_cloud``: every point of the
        cloud, the plane fit's outliers included (a datum with form beyond the plane fit's
        window has its highest and lowest regions among them)
    cov : (4, 4) float or None; only ``with_cov``: the covariance of ``(A, B, C, D)`` (unitless
        normal, mm), tracker frame: the robust fit's of a cloud, the JSON's ``covariance``, or
        None (a JSON without one: the plane is taken as exact)
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        plane = Plane.from_json(path)
        cov = (plane_covariance_from_json(path),) if with_cov else ()
        return (plane, None) + ((None,) if with_cloud else ()) + cov
    from metrology.io.clouds import read_cloud
    from metrology.datum import fit_plane_robust

    points = read_cloud(path)
    try:
        fit = fit_plane_robust(points)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    cov = (np.asarray(fit.covariance, float),) if with_cov else ()
    return (fit.plane, points[fit.inliers(points)]) + ((points,) if with_cloud else ()) + cov


@dataclass(frozen=True)
class Dataset:
    """Poses, readings, datum and layout of one run, in the layout's sensor order.

    Attributes
    ----------
    export : TrackerExport (columns in ``layout.names`` order)
    layout : SensorLayout (nominal or calibrated)
    plane : Plane, tracker frame
    datum_points : (m, 3) float, mm, tracker frame, or None: the plane fit's inliers
    datum_cloud : (k, 3) float, mm, tracker frame, or None: every point of the datum cloud
    plane_cov : (4, 4) float or None: covariance of the plane's ``(A, B, C, D)`` (unitless
        normal, mm), tracker frame; None: the plane is taken as exact
    dropped : tuple of (pose_id, sensor name)
        Readings equal to the "no reading" code, dropped on loading (see :func:`drop_no_reading`).
    no_reading : float
        That code.
    """

    export: TrackerExport
    layout: SensorLayout
    plane: Plane
    datum_points: np.ndarray | None = None
    dropped: tuple = ()
    no_reading: float = NO_READING
    datum_cloud: np.ndarray | None = None
    plane_cov: np.ndarray | None = None

    @property
    def obs(self) -> Observations:
        """The datum in each pose's TCS and the readings."""
        from metrology.core.frames import plane_in_tcs

        normal, offset = plane_in_tcs(self.plane.normal, self.plane.offset, self.export.tcs2tracker_rot,
                                      self.export.tcs2tracker_trans)
        return Observations(normal, offset, self.export.d)

    def select(self, idx) -> "Dataset":
        return Dataset(self.export.select(idx), self.layout, self.plane, self.datum_points, self.dropped,
                       self.no_reading, self.datum_cloud, self.plane_cov)

    def no_reading_summary(self) -> str | None:
        """One line on the dropped "no reading" codes (for stderr), or None when none was."""
        if not self.dropped:
            return None
        poses = sorted({p for p, _ in self.dropped})
        shown = ", ".join(f"{p} d_{n}" for p, n in self.dropped[:4]) + (", ..." if len(self.dropped) > 4 else "")
        return (f"{len(self.dropped)} reading(s) equal to the no-reading code {self.no_reading:g} dropped in "
                f"{len(poses)} pose(s) ({shown}); not used as distances")

    def no_reading_dict(self) -> dict:
        """The dropped codes for a JSON report: value, count and (pose_id, sensor) pairs."""
        return {"value": self.no_reading, "dropped": len(self.dropped),
                "readings": [{"pose_id": p, "sensor": n} for p, n in self.dropped]}


def drop_no_reading(export: TrackerExport, layout: SensorLayout, value=None) -> tuple:
    """Readings equal to the PLC's "no reading" code become NaN (no reading), never a distance.

    One rule for all values that are not distances: an empty cell and the code ``value`` are no
    reading (dropped, counted); any other reading outside the sensor's ``range_mm`` is refused by
    :func:`check`, naming the pose. The default code :data:`NO_READING` (0) applies to the sensors
    whose range does not contain it; an explicit ``value`` applies to every sensor.

    Parameters
    ----------
    export : TrackerExport, columns in ``layout.names`` order
    layout : SensorLayout
    value : float, optional, mm

    Returns
    -------
    export : TrackerExport, the codes replaced by NaN
    dropped : tuple of (pose_id, sensor name), in file order
    """
    from dataclasses import replace

    code = NO_READING if value is None else float(value)
    if not np.isfinite(code):
        raise ValueError(f"--no-reading {value}: expected a finite number")
    hit = export.d == code
    if value is None:
        lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
        hit &= ~((lo <= code) & (code <= hi))
    if not np.any(hit):
        return export, ()
    dropped = tuple((export.pose_id[p], export.names[i]) for p, i in np.argwhere(hit))
    return replace(export, d=np.where(hit, np.nan, export.d)), dropped


#: readings outside their sensor's range dropped as blanks (with a warning naming them) when
#: they are at most this share of the readings (rounded down): a planned pose that a real
#: head, not quite the nominal one, reads just past its range. More is an error (a unit, a code).
MAX_OUT_OF_RANGE_SHARE = 0.02
#: ... and each lies at most this share of its range's span past the range (5 mm on [15, 65]):
#: a reading far past it, or one value repeated (a PLC code), is not a reading of the datum
NEAR_RANGE_SHARE = 0.1


def drop_out_of_range(export: TrackerExport, layout: SensorLayout, source="export", warn=None) -> TrackerExport:
    """Readings outside their sensor's range become blanks (NaN) when they are few (at most
    :data:`MAX_OUT_OF_RANGE_SHARE` of the readings), each just past the range (at most
    :data:`NEAR_RANGE_SHARE` of its span) and no two equal (a code), each named in one
    ``warn(line)``; otherwise they are left for :func:`check` to refuse. ``export``'s columns
    are in ``layout.names`` order."""
    from dataclasses import replace

    lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
    finite = np.isfinite(export.d)
    bad = finite & ((export.d < lo) | (export.d > hi))
    n_bad, allowed = int(bad.sum()), int(MAX_OUT_OF_RANGE_SHARE * finite.sum())
    if n_bad == 0 or n_bad > allowed:
        return export
    near = NEAR_RANGE_SHARE * (hi - lo)
    past = np.maximum(lo - export.d, export.d - hi)
    if np.any(bad & ~(past <= near)) or len(np.unique(export.d[bad])) < n_bad:
        return export
    if warn is not None:
        named = ", ".join(f"pose {export.pose_id[p]} d_{layout.names[i]} = {export.d[p, i]:g} mm "
                          f"(range [{lo[i]:g}, {hi[i]:g}])" for p, i in np.argwhere(bad))
        warn(f"{source}: {n_bad} of {int(finite.sum())} readings outside their sensor's range dropped as blanks "
             f"(at most {MAX_OUT_OF_RANGE_SHARE:.0%} are): {named}")
    return replace(export, d=np.where(bad, np.nan, export.d))


def _range_hint(d, bad, lo, hi) -> str:
    """What the out-of-range readings look like: another unit, or a repeated "no reading" code."""
    finite = np.isfinite(d)
    if bad.sum() > 0.5 * finite.sum():
        for factor, what in ((1000.0, "metres"), (1e-3, "microns")):
            scaled = d * factor
            if np.mean(((lo <= scaled) & (scaled <= hi))[finite]) > 0.9:
                return f"; the readings look like {what} (x{factor:g} puts them in range): write them in mm"
    uniq, counts = np.unique(d[bad], return_counts=True)
    k = int(np.argmax(counts))
    if counts[k] >= 2:
        return (f"; {counts[k]} of them read exactly {uniq[k]:g}: if that is the PLC's 'no reading' code, "
                f"pass --no-reading {uniq[k]:g}")
    return ""


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
            + _range_hint(export.d, bad, lo, hi)
        )
    counts = np.isfinite(export.d).sum(axis=0)
    if np.any(counts < MIN_READINGS):
        i = int(np.argmin(counts))
        raise ValueError(f"{source}: sensor {layout.names[i]} has {counts[i]} readings, need at least {MIN_READINGS} "
                         "(5 parameters per sensor)")
    return export


def load_dataset(export_path, plane_path, layout_path, quaternion_order: str = "wxyz", position_units: str = "mm",
                 no_reading=None, warn=None) -> Dataset:
    """Read and cross-check the three files of a run (errors name the file and the problem).

    ``quaternion_order`` and ``position_units`` are passed to
    :func:`~metrology.io.export.read_export`; ``no_reading`` is the PLC's "no reading" code
    (default 0, see :func:`drop_no_reading`); a few readings out of range are dropped as
    blanks with a ``warn(line)`` naming them (:func:`drop_out_of_range`).
    """
    layout = load_layout(layout_path)
    export = read_export(export_path, quaternion_order, position_units)
    if sorted(export.names) == sorted(layout.names):
        export = export.reordered(layout.names)
        export, dropped = drop_no_reading(export, layout, no_reading)
        export = drop_out_of_range(export, layout, str(export_path), warn)
    else:
        dropped = ()
    export = check(export, layout, str(export_path))
    plane, points, cloud, plane_cov = load_plane(plane_path, with_cloud=True, with_cov=True)
    return Dataset(export, layout, plane, points, dropped, NO_READING if no_reading is None else float(no_reading),
                   cloud, plane_cov)
