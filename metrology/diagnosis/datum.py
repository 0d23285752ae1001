"""The datum check: the form the tracker cloud measures, against the readings' own."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects import PlaneForm
from metrology.core.model import jacobian_raw
from metrology.diagnosis.fit import Fit, FitData
from metrology.diagnosis import rules
from metrology.diagnosis.results import Param

# ``PlaneGiven`` (diagnosis/planegiven) is named in an annotation only (a string)

__all__ = ["SpotWindow", "FormAgreement", "DatumFormCheck", "datum_form", "form_agreement", "FORM_QUADRATIC", "MIN_FORM_POINTS", "DatumPlaneCheck",
           "datum_plane", "name_datum_plane"]

#: the datum form's quadratic coefficients (bow, saddle, twist), compared cloud against readings
FORM_QUADRATIC = PlaneForm.key_params
#: fewest cloud points under the spots' footprint to fit the form there (else the whole cloud)
MIN_FORM_POINTS = 50


@dataclass(frozen=True)
class SpotWindow:
    """The box of the spots' in-plane positions, the datum plane's ``(s, t)`` axes about the
    cloud's centre (:func:`~metrology.core.plane.plane_basis`).

    s, t : (2,) tuple of float, mm, ``(lo, hi)`` along each axis."""

    s: tuple
    t: tuple

    def to_dict(self) -> dict:
        return {"s": list(self.s), "t": list(self.t)}


@dataclass(frozen=True)
class FormAgreement:
    """The datum form's quadratic coefficients, the cloud's against the readings' (:func:`form_agreement`).

    readings, readings_stderr : dict, coefficient (:data:`FORM_QUADRATIC`) -> float, mm, the
    readings' ``plane_form`` and its standard error; z : dict, the same keys -> float, their
    difference from the cloud's in combined standard errors; chi2 : float, the Wald statistic (3 dof,
    both full covariances); p : float, its p-value, or, for a form named as scanned, the gain's
    (``scan_gain``); agree : bool, at ``alpha_form`` (:func:`~metrology.diagnosis.rules.datum_agrees`);
    fitted_with : tuple of str, the labels of the fit that gave the readings' form (set by
    :func:`metrology.diagnosis.decide.check_datum`); scan_gain, scan_gain_stderr : float or None
    (unitless), the gain at which the readings see the scanned form, where the form named is the
    scan itself (its p is then the two-sided z-test of gain 1).
    """

    readings: dict
    readings_stderr: dict
    z: dict
    chi2: float
    p: float
    agree: bool
    fitted_with: tuple = ()
    scan_gain: float | None = None
    scan_gain_stderr: float | None = None

    def to_dict(self) -> dict:
        out = {"readings": self.readings, "readings_stderr": self.readings_stderr, "z": self.z, "chi2": self.chi2,
               "p": self.p, "agree": self.agree, "fitted_with": list(self.fitted_with)}
        if self.scan_gain is not None:
            out.update(scan_gain=self.scan_gain, scan_gain_stderr=self.scan_gain_stderr)
        return out


@dataclass(frozen=True)
class DatumFormCheck:
    """The datum's form measured by the tracker cloud (:func:`datum_form`).

    Attributes
    ----------
    points, points_used : int; window : str, ``"under the spots"`` or ``"whole cloud"``
    window_mm : SpotWindow, the spots' box, mm
    radius_mm : float; params : dict, parameter name -> :class:`~metrology.diagnosis.results.Param`,
        the form's parameters (``PlaneForm``'s, in its order)
    p_quadratic : float, Wald test of the quadratic part against zero
    values : (5,) float, mm, the form's values; cov : (5, 5) float, mm^2, their covariance
    visible_rms_mm : list of float, per sensor; visible_over_noise : list of float
    against_readings : FormAgreement or None, :func:`form_agreement` with ``fitted_with`` (after a diagnosis)
    """

    points: int
    points_used: int
    window: str
    window_mm: SpotWindow
    radius_mm: float
    params: dict[str, Param]
    p_quadratic: float
    values: np.ndarray
    cov: np.ndarray
    visible_rms_mm: list
    visible_over_noise: list
    against_readings: FormAgreement | None = None

    def to_dict(self) -> dict:
        out = {"points": self.points, "points_used": self.points_used, "window": self.window,
               "window_mm": self.window_mm.to_dict(), "radius_mm": self.radius_mm,
               "params": {k: v.to_dict() for k, v in self.params.items()},
               "p_quadratic": self.p_quadratic, "visible_rms_mm": self.visible_rms_mm,
               "visible_over_noise": self.visible_over_noise}
        if self.against_readings is not None:
            out["against_readings"] = self.against_readings.to_dict()
        return out


def datum_form(ds, data: FitData, zero, u, d0) -> DatumFormCheck:
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

    data : FitData, the readings (``obs``), their covariates (``cov``) and noise (``sigma (n,)
    float, mm``); zero : (n, 3) float, mm, TCS, u : (n, 3) float, unit, TCS: the base
    calibration; d0 : (p, n) float, mm, its readings.
    """
    obs, cov, sigma = data.obs, data.cov, data.sigma
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
    params = {k: Param(**v) for k, v in form.describe()["params"].items()}
    return DatumFormCheck(
        int(len(pts)), int(under.sum()), window,
        SpotWindow((float(spots[:, 0].min()), float(spots[:, 0].max())), (float(spots[:, 1].min()), float(spots[:, 1].max()))),
        form.radius_mm, params, float(stats.chi2.sf(wald, 3)), form.values, C,
        visible, [v / s for v, s in zip(visible, sigma)])


def form_agreement(datum: DatumFormCheck, readings_fit: Fit) -> FormAgreement:
    """Quadratic coefficients of the cloud against those of the ``plane_form`` fitted to the
    readings: per coefficient the difference in combined standard errors, and the Wald
    chi-square (3 dof, both full covariances) with its p-value; ``agree`` at ``alpha_form``
    (``fitted_with`` left empty: the caller knows the fit's labels)."""
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
    return FormAgreement(dict(zip(FORM_QUADRATIC, v_r.tolist())),
                         dict(zip(FORM_QUADRATIC, np.sqrt(np.diag(C_r)).tolist())),
                         dict(zip(FORM_QUADRATIC, z.tolist())), wald, p, rules.datum_agrees(p))


# -- the datum plane's own uncertainty (issue 40) ----------------------------------------------------

#: the summary's sentence when the readings place the plane off its scan beyond the scan's uncertainty
DATUM_PLANE_OFF = (" The datum plane the readings place is {tilt:.0f} urad and {offset:.1f} um off the scan's, beyond "
                   "the scan's stated uncertainty (p = {p:.1e}): the datum's (re-scan the plate), not the tracker's.")


@dataclass(frozen=True)
class DatumPlaneCheck:
    """The datum plane estimated with the sensors under its scan's covariance, and whether it is
    off the scan's plane by more than that covariance allows.

    Attributes
    ----------
    given : bool, the plane came with a covariance (a cloud, or a ``plane.json`` keeping it);
        False: taken as exact, nothing estimated
    phi : (3,) float, rad, rad, mm: the plane's correction (two tilts, offset), tracker frame
    prior_stderr, posterior_stderr : (3,) float, the same units: before and after the readings
    chi2 : float, ``phi`` against its null covariance (prior - posterior), ``dof`` directions
    p : float; off : bool, :func:`metrology.diagnosis.rules.datum_plane_off`
    tilt_rad : float, the correction's tilt; normal, offset : the plane the diagnosis used
    given : PlaneGiven or None, the correction tested given the causes named
    (:func:`metrology.diagnosis.planegiven.plane_given_causes`), where the first test found it off:
    ``off`` is then that test's; screen_p : float or None, the first test's p, where ``given`` is set
    """

    given: bool
    phi: np.ndarray | None = None
    prior_stderr: np.ndarray | None = None
    posterior_stderr: np.ndarray | None = None
    chi2: float = 0.0
    dof: int = 0
    p: float = 1.0
    off: bool = False
    tilt_rad: float = 0.0
    normal: np.ndarray | None = None
    offset: float | None = None
    given_causes: "PlaneGiven | None" = None
    screen_p: float | None = None

    def to_dict(self) -> dict:
        if not self.given:
            return {"covariance_given": False,
                    "note": "the plane came without a covariance: taken as exact (give the cloud, or a plane.json "
                            "from metro fit-plane, which keeps it)"}
        return {"covariance_given": True, "correction": {"tilt_urad": (1e6 * self.phi[:2]).tolist(),
                                                         "offset_um": float(1e3 * self.phi[2])},
                "prior_stderr": {"tilt_urad": (1e6 * self.prior_stderr[:2]).tolist(),
                                 "offset_um": float(1e3 * self.prior_stderr[2])},
                "posterior_stderr": {"tilt_urad": (1e6 * self.posterior_stderr[:2]).tolist(),
                                     "offset_um": float(1e3 * self.posterior_stderr[2])},
                "chi2": self.chi2, "dof": self.dof, "p": self.p, "off": self.off,
                "used": "the plane the readings place (the base model's null includes the datum's uncertainty)",
                "given_causes": None if self.given_causes is None else self.given_causes.to_dict(),
                "screen_p": self.screen_p}


def datum_plane(ds, widen: bool = True):
    """The datum plane estimated with every sensor's base model under the scan's covariance
    (:func:`metrology.calibration.datum_prior.fit_with_datum`, each sensor whitened by its own
    scatter), and the data set on that plane: a residual pattern a plane within its stated
    uncertainty explains is then no cause. The innovation test: the correction ``phi`` against its
    null covariance ``prior - posterior`` (chi-square over the directions the readings inform).
    A plane off is placed under a prior :data:`~metrology.diagnosis.rules.DATUM_OFF_PRIOR_WIDEN`
    times wider unless ``widen`` is False (the plane under the scan's covariance, as when not off).

    Returns (Dataset on the plane the readings place, or ``ds`` itself; DatumPlaneCheck).
    """
    from dataclasses import replace

    from scipy import stats

    from metrology.calibration.datum_prior import fit_with_datum
    from metrology.calibration.estimators import lsq
    from metrology.core.plane import Plane

    if ds.plane_cov is None:
        return ds, DatumPlaneCheck(False)
    cal = lsq(ds.layout, ds.obs)
    if not (np.all(np.isfinite(cal.theta)) and np.all(np.isfinite(cal.sigma_mm)) and np.all(cal.sigma_mm > 0)):
        return ds, DatumPlaneCheck(False)
    _, nuis = fit_with_datum(ds.layout, ds.export, ds.plane.normal, ds.plane.offset, ds.plane_cov, cal.theta,
                             cal.sigma_mm, move=True)
    S = nuis.prior - nuis.posterior
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    keep = w > 1e-6 * max(float(np.max(w)), 1e-300)
    z = (V[:, keep].T @ nuis.phi) / np.sqrt(w[keep])
    chi2, dof = float(z @ z), int(keep.sum())
    p = float(stats.chi2.sf(chi2, dof)) if dof else 1.0
    off = rules.datum_plane_off(p)
    prior = nuis.prior
    if off and widen:  # the scan is off: the plane the readings place, under a much wider prior
        _, nuis = fit_with_datum(ds.layout, ds.export, ds.plane.normal, ds.plane.offset,
                                 ds.plane_cov * rules.DATUM_OFF_PRIOR_WIDEN**2, cal.theta, cal.sigma_mm, move=True)
    check = DatumPlaneCheck(True, nuis.phi, np.sqrt(np.diag(prior)), np.sqrt(np.maximum(np.diag(nuis.posterior), 0)),
                            chi2, dof, p, off, float(np.hypot(*nuis.phi[:2])), nuis.normal, nuis.offset)
    return replace(ds, plane=Plane(nuis.normal, nuis.offset)), check


def name_datum_plane(diag, check: DatumPlaneCheck):
    """The diagnosis with the datum plane check attached; a plane off beyond its uncertainty (given
    the causes named, :attr:`DatumPlaneCheck.given_causes`) is named ``datum_tilt`` (the datum's, not a
    pose error): the headline where nothing else is named, else beside the causes named, after them
    (the headline is the cause of the largest held-out gain, rule 18); not where ``plane_form`` is
    named (the datum's form, of which the plane's move is a part)."""
    from dataclasses import replace

    from metrology.diagnosis.results import Cause, Confidence, Decision, Reason, Size

    diag = replace(diag, datum_plane=check)
    # a form named is the datum's already (plane_form): the plane's move is part of it
    if not check.off or any(c.cause == "plane_form" for c in diag.causes):
        return diag
    g = check.given_causes
    p = check.p if g is None else g.p
    cause = Cause("datum_tilt", "datum_tilt", [], Size(check.tilt_rad, None, "rad", "tilt of the datum plane the "
                                                       "readings place from the scan's"),
                  check.chi2 if g is None else g.chi2, None, p, 0,
                  test="the plane's correction against the scan's covariance (chi-square)" + (
                      "" if g is None or not g.given else ", given the causes named"),
                  params={name: Param(float(check.phi[i]), unit,
                                      None if check.posterior_stderr is None else float(check.posterior_stderr[i]))
                          for i, (name, unit) in enumerate((("tilt_1", "rad"), ("tilt_2", "rad"), ("offset", "mm")))})
    summary = diag.summary.rstrip(".") + "." + DATUM_PLANE_OFF.format(tilt=1e6 * check.tilt_rad, offset=1e3 * check.phi[2], p=p)
    named = diag.cause not in ("none", "unexplained")
    why = Reason(18, "datum_plane_off", Decision.DATUM_PLANE_OFF, ("datum_tilt",) + (() if g is None else g.given),
                 "p of the plane's correction against the scan's covariance (chi-square)" + (
                     "" if g is None or not g.given else ", given the causes named"), p,
                 rules.ALPHA_DATUM_PLANE, outcome="datum_tilt")
    if named:  # the headline stays the cause of the largest held-out gain; the datum's finding beside it
        return replace(diag, summary=summary, reasons=diag.reasons + (why,), causes=tuple(diag.causes) + (cause,))
    return replace(diag, cause="datum_tilt", sensors=[], summary=summary, named=cause, reasons=diag.reasons + (why,),
                   confidence=Confidence.HIGH if p < 1e-6 else Confidence.MODERATE, causes=(cause,))
