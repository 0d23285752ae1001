"""The covariates a cause can depend on, and the candidate components tried for a layout."""

from __future__ import annotations

import numpy as np
from metrology.core.effects import REGISTRY, Covariates
from metrology.core.layout import SensorLayout
from metrology.core.model import readings


#: the poses that separate each cause from the others (read from the registry)
ADVICE = {name: cls.advice for name, cls in REGISTRY.items()}


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
        for cls in REGISTRY.values():
            if cls.per_sensor:
                out += cls.candidates(i, names, cov, flags)
    for cls in REGISTRY.values():
        if not cls.per_sensor:
            out += cls.candidates(None, names, cov, flags)
    return out
