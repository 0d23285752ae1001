"""The datum check: the form the tracker cloud measures, against the readings' own."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects import Covariates, PlaneForm
from metrology.core.model import jacobian_raw
from metrology.diagnosis.fit import Fit
from metrology.diagnosis import rules

__all__ = ["DatumFormCheck", "datum_form", "form_agreement", "FORM_QUADRATIC", "MIN_FORM_POINTS"]

#: the datum form's quadratic coefficients (bow, saddle, twist), compared cloud against readings
FORM_QUADRATIC = PlaneForm.key_params
#: fewest cloud points under the spots' footprint to fit the form there (else the whole cloud)
MIN_FORM_POINTS = 50


@dataclass(frozen=True)
class DatumFormCheck:
    """The datum's form measured by the tracker cloud (:func:`datum_form`).

    Attributes
    ----------
    points, points_used : int; window : str, ``"under the spots"`` or ``"whole cloud"``
    window_mm : dict, the spots' box ``{"s": [lo, hi], "t": [lo, hi]}`` mm
    radius_mm : float; params : dict, the form's parameters (value, unit, stderr)
    p_quadratic : float, Wald test of the quadratic part against zero
    values : (5,) float, mm, the form's values; cov : (5, 5) float, mm^2, their covariance
    visible_rms_mm : list of float, per sensor; visible_over_noise : list of float
    against_readings : dict or None, :func:`form_agreement` with ``fitted_with`` (after a diagnosis)
    """

    points: int
    points_used: int
    window: str
    window_mm: dict
    radius_mm: float
    params: dict
    p_quadratic: float
    values: np.ndarray
    cov: np.ndarray
    visible_rms_mm: list
    visible_over_noise: list
    against_readings: dict | None = None

    def to_dict(self) -> dict:
        out = {"points": self.points, "points_used": self.points_used, "window": self.window,
               "window_mm": self.window_mm, "radius_mm": self.radius_mm, "params": self.params,
               "p_quadratic": self.p_quadratic, "visible_rms_mm": self.visible_rms_mm,
               "visible_over_noise": self.visible_over_noise}
        if self.against_readings is not None:
            out["against_readings"] = self.against_readings
        return out


def datum_form(ds, zero, u, obs, cov: Covariates, d0, sigma) -> DatumFormCheck:
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
    return DatumFormCheck(
        int(len(pts)), int(under.sum()), window,
        {"s": [float(spots[:, 0].min()), float(spots[:, 0].max())], "t": [float(spots[:, 1].min()), float(spots[:, 1].max())]},
        form.radius_mm, params, float(stats.chi2.sf(wald, 3)), form.values, C,
        visible, [v / s for v, s in zip(visible, sigma)])


def form_agreement(datum: DatumFormCheck, readings_fit: Fit) -> dict:
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
            "agree": rules.datum_agrees(p)}
