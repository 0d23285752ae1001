"""Calibrate a dataset: the estimator, its uncertainties and identifiability, as one report object."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
import numpy as np
from metrology.calibration.dataset import Dataset
from metrology.calibration.estimators import DEFAULT_METHOD, METHODS, Calibration, calibrate
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis
from metrology.core.tolerances import CORRELATION_REPORT, TARGET_TILT_DEG, TARGET_ZERO_MM
from metrology.core.verdict import Check, Verdict
from metrology.core.paper import EKF_PRESETS
from metrology.calibration.identifiability import CHART_NAMES, identifiability

#: model adequacy: a sensor's residuals are above its stated noise when the chi-square of its
#: readings (dof = readings - 5) has a one-sided p below this (one false alarm in 1000 runs)
MODEL_ADEQUACY_ALPHA = 1e-3

#: coverage factor of the expanded uncertainty U = k u the datum's share is stated in (the certificate's,
#: metrology.report.certificate.COVERAGE_K: GUM 6.2)
COVERAGE_K = 2.0

#: the paper's EKF runs with the experiment's settings (section 6) unless told otherwise
_METHOD_DEFAULTS = {"ekf_paper": EKF_PRESETS["experiment"]}


def _correlations(cov):
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    out = []
    for a in range(5):
        for b in range(a + 1, 5):
            if se[a] > 0 and se[b] > 0:
                r = float(cov[a, b] / (se[a] * se[b]))
                if abs(r) > CORRELATION_REPORT:
                    out.append({"a": CHART_NAMES[a], "b": CHART_NAMES[b], "r": r})
    return out


@dataclass(frozen=True)
class CalibrationReport:
    """A calibration from measured files, with its uncertainty and identifiability.

    Attributes
    ----------
    calibration : Calibration
        The estimator's fitted copy (``.layout`` is the calibrated layout).
    dataset : Dataset
        The data it was fitted to (nominal layout).
    identifiability : list of Identifiability
    sources : dict of str -> str
        Where the inputs came from (for the report).
    target : (float, float) or None
        The precision target: zero point 1 sigma (mm) and beam tilt 1 sigma (rad).
    target_set : bool
        Whether the user set ``target`` (it gates the verdict) or it is the default (information).
    certificate : object or None
        The calibration certificate of the calibrated layout as written
        (:class:`metrology.report.certificate.Certificate`, made by the file job), else None.
    """

    calibration: Calibration
    dataset: Dataset
    identifiability: list
    sources: dict = field(default_factory=dict)
    target: tuple | None = None
    target_set: bool = False
    certificate: object = None
    #: the head's effect terms estimated with the sensors (:class:`metrology.calibration.terms.TermFit`), or None
    terms: object = None

    @cached_property
    def convergence(self) -> list:
        """:func:`~metrology.calibration.convergence.batch_convergence` of this run (a batch method): one refit per
        pose count, computed once a report (``calibrate --report --plot`` draws it for the page and the plot file)."""
        from metrology.calibration.convergence import batch_convergence

        return batch_convergence(self.calibration.nominal, self.dataset.obs, self.calibration.method)

    @property
    def layout(self) -> SensorLayout:
        return self.calibration.layout

    @property
    def warnings(self) -> list:
        return [w for ident in self.identifiability for w in ident.warnings]

    def adequacy(self) -> list:
        """Model adequacy per sensor: (name, residual RMS mm, the RMS the stated noise allows at
        :data:`MODEL_ADEQUACY_ALPHA` mm, p-value); sensors without a stated noise or dof are left out."""
        from scipy import stats

        cal = self.calibration
        out = []
        for i, name in enumerate(cal.nominal.names):
            n, noise, rms = int(cal.n_used[i]), float(cal.nominal.noise_mm[i]), float(cal.residual_rms[i])
            dof = n - 5
            if dof > 0 and noise > 0 and np.isfinite(rms):
                chi2 = n * (rms / noise) ** 2
                limit = noise * float(np.sqrt(stats.chi2.isf(MODEL_ADEQUACY_ALPHA, dof) / n))
                out.append((name, rms, limit, float(stats.chi2.sf(chi2, dof))))
        return out

    def verdict(self) -> Verdict:
        """What the calibration is judged on, each check named for what it judges:

        - ``model adequacy``: each sensor's residual RMS against what its stated noise allows
          (chi-square, one-sided at :data:`MODEL_ADEQUACY_ALPHA`). Information: the stated noise
          is an assumption, not a tolerance (``metro diagnose`` names what is missed).
        - ``precision target``: the largest predicted 1 sigma of the zero points (mm) and beam
          tilts (deg) against the target; gates only when the user set it (``target_set``).
        """
        checks = [Check(f"model adequacy: {name} residual RMS against its stated noise", rms, limit, "mm",
                        bool(p >= MODEL_ADEQUACY_ALPHA), gate=False)
                  for name, rms, limit, p in self.adequacy()]
        if self.target is not None and self.identifiability:
            pse = np.array([ident.predicted_stderr for ident in self.identifiability])
            z, t = float(np.max(pse[:, :3])), float(np.rad2deg(np.max(pse[:, 3:])))
            tz, tt = float(self.target[0]), float(np.rad2deg(self.target[1]))
            how = "" if self.target_set else " (default target)"
            checks += [Check(f"precision target: zero points, largest 1σ{how}", z, tz, "mm", bool(z <= tz),
                             gate=self.target_set),
                       Check(f"precision target: beam tilts, largest 1σ{how}", t, tt, "deg", bool(t <= tt),
                             gate=self.target_set)]
        cal = self.calibration
        if cal.datum is None:
            checks.append(Check("datum: the plane is taken as exact (no covariance given: a plane.json without "
                                "'covariance'); the calibration's uncertainty is conditional on it", 0.0, None, "",
                                True, gate=False))
        else:
            checks.append(Check("datum: its uncertainty (the scan's covariance) estimated with the sensors; "
                                "largest share of a parameter's variance", float(np.max(cal.datum.share)), None, "",
                                True, gate=False))
        return Verdict(tuple(checks))

    def datum_share(self) -> dict:
        """The datum's part of the expanded uncertainty (k = 2) of every parameter, per sensor:
        ``U_datum`` (zero points mm, tilts deg) and ``U`` (total), and the share of the variance;
        ``{"exact": True}`` when the plane was taken as exact."""
        cal = self.calibration
        if cal.datum is None:
            return {"exact": True, "note": "no covariance given with the plane: taken as exact, not in U"}
        ud = cal.datum.stderr_datum.reshape(-1, 5)
        ut = np.sqrt(np.maximum(np.diag(cal.datum.cov_marginal), 0.0)).reshape(-1, 5)
        sh = cal.datum.share.reshape(-1, 5)
        out = {"exact": False, "coverage_factor": COVERAGE_K, "sensors": []}  # k = 2, as the certificate
        for i, name in enumerate(cal.nominal.names):
            out["sensors"].append({"name": name,
                                   "U_zero_mm": (COVERAGE_K * ut[i, :3]).tolist(),
                                   "U_datum_zero_mm": (COVERAGE_K * ud[i, :3]).tolist(),
                                   "U_tilt_deg": np.rad2deg(COVERAGE_K * ut[i, 3:]).tolist(),
                                   "U_datum_tilt_deg": np.rad2deg(COVERAGE_K * ud[i, 3:]).tolist(),
                                   "share_of_variance": sh[i].tolist()})
        return out

    def datum_statement(self) -> str:
        """One line for the certificate: the datum's share of U (k = 2), or that it was taken as exact."""
        cal = self.calibration
        if cal.datum is None:
            return "datum plane taken as exact (no covariance given); its uncertainty is not in U"
        d = cal.datum.to_dict()
        ud = cal.datum.stderr_datum.reshape(-1, 5)
        sh = cal.datum.share.reshape(-1, 5)
        return (f"datum plane estimated with the sensors under the scan's covariance (tilt 1σ "
                f"{d['prior_stderr']['tilt_urad'][0]:.1f}, {d['prior_stderr']['tilt_urad'][1]:.1f} µrad, offset "
                f"{d['prior_stderr']['offset_um']:.2f} µm); its part of U (k = 2): zero points up to "
                f"{2e3 * float(np.max(ud[:, :3])):.2f} µm ({100 * float(np.max(sh[:, :3])):.0f} % of the variance), "
                f"tilts up to {np.rad2deg(2 * float(np.max(ud[:, 3:]))):.5f} deg "
                f"({100 * float(np.max(sh[:, 3:])):.0f} %)")

    def to_dict(self) -> dict:
        """The report as plain data; ``no_reading`` (value, count, readings) only when codes were dropped."""
        cal, nom = self.calibration, self.calibration.nominal
        basis = direction_basis(nom.direction)
        se = cal.stderr
        sensors = []
        for i, name in enumerate(nom.names):
            n_conv = None
            if len(cal.n_converged):
                n_conv = int(cal.n_converged[i]) if cal.n_converged[i] >= 0 else None
            tilt = np.arctan(cal.theta[i, 3:])
            total = float(np.arccos(np.clip(cal.layout.direction[i] @ nom.direction[i], -1.0, 1.0)))
            sensors.append({
                "name": name,
                "n_readings": int(cal.n_used[i]),
                "noise_mm": nom.noise_mm[i],
                "residual_rms_mm": cal.residual_rms[i],
                "n_converged": n_conv,
                "nominal": {"zero_mm": nom.zero[i], "direction": nom.direction[i]},
                "error": {"zero_mm": cal.theta[i, :3], "zero_stderr_mm": se[i, :3],
                          "tilt_deg": np.rad2deg(tilt), "tilt_stderr_deg": np.rad2deg(se[i, 3:]),
                          "tilt_total_deg": np.rad2deg(total), "chart_axes": basis[i],
                          "paper_delta": dict(zip(("dx", "dy", "dz", "dm", "dn", "dq"), cal.delta_raw[i]))},
                "corrected": {"zero_mm": cal.layout.zero[i], "zero_stderr_mm": se[i, :3],
                              "direction": cal.layout.direction[i], "direction_stderr_deg": np.rad2deg(se[i, 3:])},
                "correlations": _correlations(cal.cov[i]),
            })
        out = {
            "method": cal.method,
            "sources": self.sources,
            "n_poses": self.dataset.export.n_poses,
            "datum": {"normal": self.dataset.plane.normal, "offset_mm": self.dataset.plane.offset,
                      "covariance_given": self.dataset.plane_cov is not None,
                      "estimated": None if cal.datum is None else cal.datum.to_dict(),
                      "share_of_U": self.datum_share()},
            "sensors": sensors,
            "unidentified": cal.unidentified,
            "identifiability": [ident.to_dict() for ident in self.identifiability],
            "warnings": self.warnings,
            "verdict": self.verdict().to_dict(),
        }
        if self.terms is not None:
            out["effects"] = self.terms.to_dict()
        if self.certificate is not None:
            out["certificate"] = self.certificate.to_dict()
        if self.dataset.dropped:
            out["no_reading"] = self.dataset.no_reading_dict()
        return out


def cal_obs(cal, dataset):
    """The observations on the plane the calibration was fitted on (the joint fit's, else the datum's)."""
    if cal.datum is None or not cal.datum.moved:
        return dataset.obs
    from metrology.core.frames import plane_in_tcs
    from metrology.core.observations import Observations

    N, D = plane_in_tcs(cal.datum.normal, cal.datum.offset, dataset.export.tcs2tracker_rot,
                        dataset.export.tcs2tracker_trans)
    return Observations(N, D, dataset.export.d)


def with_datum(cal, dataset):
    """``cal`` with the datum plane estimated jointly as a nuisance under the scan's covariance
    (:func:`metrology.calibration.datum_prior.fit_with_datum`): for ``lsq`` the joint estimate
    and its covariance; for another estimator its own estimate with the datum's share added to
    its covariance. The calibrated layout's ``covariance`` is the full (5n, 5n) one: the sensors
    are correlated through the shared plane."""
    from dataclasses import replace

    from scipy.linalg import block_diag

    from metrology.calibration.datum_prior import fit_with_datum
    from metrology.calibration.fitted import _finish
    from metrology.core.model import chart_cov_recentred

    move = cal.method == "lsq"
    theta, nuis = fit_with_datum(cal.nominal, dataset.export, dataset.plane.normal, dataset.plane.offset,
                                 dataset.plane_cov, cal.theta, cal.sigma_mm, move=move)
    full = nuis.cov_marginal if move else block_diag(*cal.cov) + (nuis.cov_marginal - nuis.cov_conditional)
    full = 0.5 * (full + full.T)
    n = cal.nominal.n
    blocks = np.stack([full[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)])
    cal = replace(cal, datum=nuis)
    obs = cal_obs(cal, dataset)
    new = _finish(cal.method, cal.nominal, obs, theta, blocks, cal.sigma_mm, n_converged=cal.n_converged,
                  history=cal.history, raw_cov=cal.raw_cov, datum=nuis)
    layout = replace(new.layout, covariance=chart_cov_recentred(cal.nominal.direction, theta[:, 3:], full))
    return replace(new, layout=layout)


def calibrate_dataset(dataset: Dataset, method: str = DEFAULT_METHOD, sources=None, target=None,
                      target_set: bool = False, **kwargs) -> CalibrationReport:
    """Calibrate the sensors of ``dataset`` (its layout is the nominal) with ``method``.

    Parameters
    ----------
    dataset : Dataset
    method : str, a key of :data:`metrology.calibration.estimators.METHODS`
        ``ekf_paper`` runs with the experiment's Q, R and delta (paper section 6) unless
        given in ``kwargs``.
    sources : dict, optional
        Input file names, copied into the report.
    target : (float, float), optional
        Wanted 1-sigma of zero point (mm) and tilt (rad) for the identifiability advice and
        the verdict (None: :data:`metrology.core.tolerances.TARGET_ZERO_MM`, ``TARGET_TILT_DEG``).
    target_set : bool
        The user set ``target``: it gates the verdict (else it is information).

    Returns
    -------
    CalibrationReport
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}, expected one of {', '.join(METHODS)}")
    obs = dataset.obs
    opts = {**_METHOD_DEFAULTS.get(method, {}), **kwargs}
    terms = None
    if dataset.layout.effects is not None:  # the sensors and the layout's head terms, jointly
        from metrology.calibration.terms import check_method
        from metrology.calibration.terms_filter import calibrate_terms

        check_method(dataset.layout, method)
        cal, terms, obs = calibrate_terms(dataset, method, **opts)
        dataset = replace(dataset, export=replace(dataset.export, d=obs.d))  # the readings less the terms
        if dataset.plane_cov is not None:  # the datum estimated with the sensors on them; its share added
            from metrology.core.model import chart_cov_recentred  # to the joint fit's (the joint stays PSD)

            joint, cal = cal.layout.covariance, with_datum(cal, dataset)
            share = chart_cov_recentred(cal.nominal.direction, cal.theta[:, 3:],
                                        cal.datum.cov_marginal - cal.datum.cov_conditional)
            cal = replace(cal, layout=replace(cal.layout, covariance=joint + 0.5 * (share + share.T),
                                              effects=terms.terms))
            obs = cal_obs(cal, dataset)
    else:
        cal = calibrate(dataset.layout, obs, method, **opts)
    if terms is None and dataset.plane_cov is not None and np.all(np.isfinite(cal.theta)) and np.all(np.isfinite(cal.cov)):
        cal = with_datum(cal, dataset)
        obs = cal_obs(cal, dataset)
    if not (np.all(np.isfinite(cal.theta)) and np.all(np.isfinite(cal.cov))):
        raise ValueError(f"method {method}: the estimate is not finite (the data do not determine the parameters)")
    # the precision verdict uses the sigma the report shows: the residuals' scatter over m - 5
    # degrees of freedom (metrology.calibration.uncertainty.residual_scaled_cov), else the stated noise
    m = cal.n_used.astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        scatter = cal.residual_rms * np.sqrt(m / (m - 5))
    sigma = np.where(np.isfinite(scatter) & (scatter > 0) & (m > 5), scatter, cal.sigma_mm)
    if target is None:
        target = (TARGET_ZERO_MM, float(np.deg2rad(TARGET_TILT_DEG)))
    ident = identifiability(dataset.layout, cal.layout, cal.theta, obs, sigma, target)
    return CalibrationReport(cal, dataset, ident, dict(sources or {}), tuple(target), bool(target_set), terms=terms)
