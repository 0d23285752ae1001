"""The datum cloud as an independent witness: its form under the spots, against the readings' form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from metrology.core.effects import Covariates, PlaneForm
from metrology.core.model import jacobian_raw
from metrology.diagnosis.stats import THRESHOLDS
from metrology.diagnosis.fit import Fit


#: the datum form's quadratic coefficients (bow, saddle, twist), compared cloud against readings
FORM_QUADRATIC = ("b_ss_mm", "b_st_mm", "b_tt_mm")


#: fewest cloud points under the spots' footprint to fit the form there (else the whole cloud)
MIN_FORM_POINTS = 50


@dataclass(frozen=True)
class DatumCheck:
    """The datum cloud's form under the spots (:func:`datum_form`).

    Attributes
    ----------
    summary : dict
        The public result (``--json``'s ``datum_form``); read as ``check[key]``;
        ``against_readings`` is added once the readings' form is known.
    values : (5,) float, the form's coefficients (``PlaneForm`` parameters, mm at its radius)
    cov : (5, 5) float, their covariance
    """

    summary: dict
    values: np.ndarray
    cov: np.ndarray

    def __getitem__(self, key):
        return self.summary[key]

    def to_dict(self) -> dict:
        return dict(self.summary)


def datum_form(ds, zero, u, obs, cov: Covariates, d0, sigma) -> dict:
    """The datum's form measured by the tracker cloud, and what it would do to the readings.

    The cloud is an independent measurement of the surface the beams see:
    :meth:`~metrology.effects.PlaneForm.from_cloud` in the axes of the readings' covariates,
    fitted to the points under the spots' footprint (the box of their in-plane positions;
    the whole cloud if fewer than :data:`MIN_FORM_POINTS` fall in it), because form beyond
    quadratic gives other quadratic coefficients on other regions of a real plate.
    Its quadratic part (bow, saddle, twist) is tested against zero (Wald, chi-square with 3
    dof) and evaluated at this run's spots; ``visible_rms_mm`` is the part of that term the
    base geometry cannot absorb (per sensor, the residual of its least-squares projection on
    the base Jacobian), i.e. the misfit the form would leave in the base residuals.

    zero : (n, 3) float, mm, TCS, u : (n, 3) float, unit, TCS: the base calibration;
    d0 : (p, n) float, mm, its readings; sigma : (n,) float, mm.
    """
    from scipy import stats

    from metrology.core.plane import plane_basis

    pts = ds.datum_points
    centre = np.mean(pts, axis=0)
    # only the part of the datum the beams saw: form beyond quadratic gives other quadratic
    # coefficients on other regions of a real plate
    st = (pts - centre) @ plane_basis(ds.plane.normal).T
    spots = cov.spot_st[np.isfinite(obs.d)]
    under = np.all((st >= spots.min(axis=0)) & (st <= spots.max(axis=0)), axis=1)
    window = "under the spots" if under.sum() >= MIN_FORM_POINTS else "whole cloud"
    if window == "whole cloud":
        under = np.ones(len(pts), bool)
    form, C = PlaneForm.from_cloud(pts[under], ds.plane.normal, ds.plane.offset, centre, names=ds.layout.names)
    q, Cq = form.values[2:], C[2:, 2:]
    wald = float(q @ np.linalg.lstsq(Cq, q, rcond=None)[0])
    quad = form.with_values(np.r_[0.0, 0.0, q])
    term = quad.evaluate(quad.values, d0, cov)
    J = jacobian_raw(zero, u, obs.normal, obs.offset)
    visible = []
    for i in range(term.shape[1]):
        ok = np.isfinite(obs.d[:, i]) & np.isfinite(term[:, i])
        r = term[ok, i] - J[ok, i] @ np.linalg.lstsq(J[ok, i], term[ok, i], rcond=None)[0]
        visible.append(float(np.sqrt(np.mean(r**2))) if ok.any() else float("nan"))
    params = form.describe()["params"]
    return DatumCheck({
        "points": int(len(pts)), "points_used": int(under.sum()), "window": window,
        "window_mm": {"s": [float(spots[:, 0].min()), float(spots[:, 0].max())],
                      "t": [float(spots[:, 1].min()), float(spots[:, 1].max())]},
        "radius_mm": form.radius_mm, "params": params,
        "p_quadratic": float(stats.chi2.sf(wald, 3)),
        "visible_rms_mm": visible, "visible_over_noise": [v / s for v, s in zip(visible, sigma)],
    }, form.values, C)


def form_agreement(datum: DatumCheck, readings_fit: Fit) -> dict:
    """Quadratic coefficients of the cloud against those of the ``plane_form`` fitted to the
    readings: per coefficient the difference in combined standard errors, and the Wald
    chi-square (3 dof, both full covariances) with its p-value; ``agree`` at ``alpha_form``."""
    from scipy import stats

    off = 0
    for comp in readings_fit.components:  # extra_cov covers the components not per pose, in order
        if isinstance(comp, PlaneForm):
            break
        off += 0 if comp.per_pose else comp.n_params
    idx = [comp.param_names.index(k) for k in FORM_QUADRATIC]
    v_r = comp.values[idx]
    C_r = readings_fit.extra_cov[np.ix_([off + i for i in idx], [off + i for i in idx])]
    v_c, C_c = datum.values[2:], datum.cov[2:, 2:]
    diff = v_r - v_c
    Cd = C_r + C_c
    z = diff / np.sqrt(np.diag(Cd))
    wald = float(diff @ np.linalg.solve(Cd, diff))
    p = float(stats.chi2.sf(wald, 3))
    return {"readings": dict(zip(FORM_QUADRATIC, v_r.tolist())),
            "readings_stderr": dict(zip(FORM_QUADRATIC, np.sqrt(np.diag(C_r)).tolist())),
            "z": dict(zip(FORM_QUADRATIC, z.tolist())), "chi2": wald, "p": p,
            "agree": bool(p >= THRESHOLDS["alpha_form"])}
