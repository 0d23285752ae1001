"""The covariates a cause can depend on, and the candidate components tried for a layout."""

from __future__ import annotations

import numpy as np
from metrology.core.effects import Covariates, Drift, Incidence, Nonlinearity, Outliers, PlaneForm, PoseError, Scale
from metrology.core.layout import SensorLayout
from metrology.core.model import readings


#: the poses that separate each cause from the others
ADVICE = {
    "scale": "readings over the whole measuring range (a wider spread of stand-off)",
    "nonlinearity": "readings over the whole measuring range (a wider spread of stand-off)",
    "incidence": "a wider spread of tilt against the datum (incidence angles)",
    "drift": "poses repeated cold and warm, interleaved rather than in one sweep",
    "plane_form": "spots over the whole datum, each region seen at several tilts",
    "pose_error": "repeated poses, or more sensors per pose",
    "outliers": "the flagged poses repeated",
}


def covariates_for(ds, layout_fit: SensorLayout, centre=None) -> Covariates:
    """Covariates of a :class:`~metrology.dataset.Dataset` at the calibrated geometry.

    ``centre`` (3,) mm tracker: the datum centre; default the centroid of the datum cloud if
    there is one, else the mean of the spots projected on the plane.
    """
    obs = ds.obs
    ex = ds.export
    R, t = ex.tcs2tracker_rot, ex.tcs2tracker_trans
    rng_mm = layout_fit.range_mm.copy()
    bad = ~np.all(np.isfinite(rng_mm), axis=1)
    if np.any(bad):  # no stated range: the readings' own span
        lo, hi = np.nanmin(ex.d, axis=0), np.nanmax(ex.d, axis=0)
        rng_mm[bad] = np.stack([lo, hi], axis=1)[bad]
    if centre is None:
        if ds.datum_points is not None:
            centre = np.mean(ds.datum_points, axis=0)
        else:
            d, _ = readings(layout_fit.zero, layout_fit.direction, obs.normal, obs.offset)
            spots = np.einsum("pij,pnj->pni", R, layout_fit.zero[None] + d[..., None] * layout_fit.direction[None]) + t[:, None]
            centre = np.nanmean(spots.reshape(-1, 3), axis=0)
    centre = np.asarray(centre, float)
    centre = centre - ds.plane.distance(centre) * ds.plane.normal
    has_t = np.all(np.isfinite(ex.time_s))
    has_T = np.all(np.isfinite(ex.temp_c))
    return Covariates.from_geometry(layout_fit.zero, layout_fit.direction, obs.normal, obs.offset, R, t,
                                    ds.plane.normal, centre, rng_mm, ex.time_s if has_t else None,
                                    ex.temp_c if has_T else None)


def candidates_for(layout: SensorLayout, cov: Covariates, flags=None):
    """Every catalogued candidate component for this data set (values zero).

    ``flags`` (p, n) bool: readings flagged as gross (the ``outliers`` candidate); none if
    None or empty.
    """
    names = layout.names
    out = []
    for i in range(layout.n):
        out.append(Scale((i,), names=names))
        out.append(Incidence((i,), names=names))
        out.append(Nonlinearity((i,), names=names))
        # the reference is fixed once per data set (every fold evaluates against it) at the
        # run's mean, where the rate is least correlated with the zero point
        if np.all(np.isfinite(cov.temp_c)) and np.ptp(cov.temp_c) > 0:
            out.append(Drift((i,), names=names, variable="temp", ref=float(np.mean(cov.temp_c))))
        out.append(Drift((i,), names=names, variable="time", ref=float(np.mean(cov.time_h))))
    out.append(PlaneForm((), names=names))
    out.append(PoseError((), names=names, n_poses=cov.n_poses))
    if flags is not None and np.any(flags):
        out.append(Outliers(tuple(sorted(set(np.argwhere(flags)[:, 1].tolist()))), names=names, flags=flags))
    return out
