"""Calibrate a dataset: the estimator, its uncertainties and identifiability, as one report object."""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np
from metrology.calibration.dataset import MIN_READINGS, Dataset
from metrology.calibration.estimators import METHODS, Calibration, calibrate
from metrology.core.observations import Observations
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, readings
from metrology.core.tolerances import CORRELATION_REPORT
from metrology.core.paper import EKF_PRESETS
from metrology.calibration.identifiability import CHART_NAMES, _sigma_words, identifiability


#: the default estimator: on fixtures/measured, lsq and iekf recover the truth equally
#: well (README "Estimators compared"); lsq is the fastest and its standard errors are
#: scaled by the residual, so they stay honest when the stated noise is optimistic
DEFAULT_METHOD = "lsq"


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
    """

    calibration: Calibration
    dataset: Dataset
    identifiability: list
    sources: dict = field(default_factory=dict)

    @property
    def layout(self) -> SensorLayout:
        return self.calibration.layout

    @property
    def warnings(self) -> list:
        return [w for ident in self.identifiability for w in ident.warnings]

    def to_dict(self) -> dict:
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
        return {
            "method": cal.method,
            "sources": self.sources,
            "n_poses": self.dataset.export.n_poses,
            "datum": {"normal": self.dataset.plane.normal, "offset_mm": self.dataset.plane.offset},
            "sensors": sensors,
            "unidentified": cal.unidentified,
            "identifiability": [ident.to_dict() for ident in self.identifiability],
            "warnings": self.warnings,
        }

    def text(self) -> str:
        """A human-readable report (what ``metro calibrate`` prints)."""
        d = self.to_dict()
        lines = [f"method {d['method']}: {d['n_poses']} poses, datum normal {np.round(d['datum']['normal'], 6).tolist()} "
                 f"offset {d['datum']['offset_mm']:.4f} mm (tracker frame)"]
        for s in d["sensors"]:
            e, c = s["error"], s["corrected"]
            conv = "" if s["n_converged"] is None else f", converged after {s['n_converged']} measurements"
            lines.append(f"{s['name']}: {s['n_readings']} readings, residual RMS {s['residual_rms_mm']:.4f} mm "
                         f"(stated noise {s['noise_mm']:.4g} mm){conv}")
            lines.append("  zero error   " + "  ".join(f"{p} {v:+.4f} +- {u:.4f}" for p, v, u in
                                                      zip("xyz", e["zero_mm"], e["zero_stderr_mm"])) + " mm")
            lines.append("  beam tilt    " + "  ".join(f"{p} {v:+.4f} +- {u:.4f}" for p, v, u in
                                                      zip(("e1", "e2"), e["tilt_deg"], e["tilt_stderr_deg"]))
                         + f" deg (total {e['tilt_total_deg']:.4f} deg)")
            lines.append("  corrected    zero " + _vec(c["zero_mm"], 4) + " mm, direction " + _vec(c["direction"], 6))
            for r in s["correlations"]:
                lines.append(f"  correlation  {r['a']}-{r['b']} {r['r']:+.3f}")
        lines.append(f"unidentified: {d['unidentified']}")
        for ident in self.identifiability:
            sv = " ".join(f"{v:.2g}" for v in ident.chart_singular)
            lines.append(f"{ident.name}: chart singular values (relative) {sv}; raw null direction: {ident.raw_null_words}")
            lines.append(f"  least determined: {ident.words[-1]} (1 sigma {_sigma_words(ident.combination_sigma[-1])}; "
                         f"moves the measured normal by {np.rad2deg(ident.normal_effect[-1]):.2g} deg RMS)")
        for w in self.warnings:
            lines.append(f"warning: {w}")
        return "\n".join(lines)


def _vec(v, digits):
    return "[" + ", ".join(f"{x:.{digits}f}" for x in v) + "]"


def calibrate_dataset(dataset: Dataset, method: str = DEFAULT_METHOD, sources=None, target=None,
                      **kwargs) -> CalibrationReport:
    """Calibrate the sensors of ``dataset`` (its layout is the nominal) with ``method``.

    Parameters
    ----------
    dataset : Dataset
    method : str, a key of :data:`metrology.estimators.METHODS`
        ``ekf_paper`` runs with the experiment's Q, R and delta (paper section 6) unless
        given in ``kwargs``.
    sources : dict, optional
        Input file names, copied into the report.
    target : (float, float), optional
        Wanted 1-sigma of zero point (mm) and tilt (rad) for the identifiability advice.

    Returns
    -------
    CalibrationReport
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}, expected one of {', '.join(METHODS)}")
    obs = dataset.obs
    opts = {**_METHOD_DEFAULTS.get(method, {}), **kwargs}
    cal = calibrate(dataset.layout, obs, method, **opts)
    if not (np.all(np.isfinite(cal.theta)) and np.all(np.isfinite(cal.cov))):
        raise ValueError(f"method {method}: the estimate is not finite (the data do not determine the parameters)")
    sigma = np.where(np.isfinite(cal.residual_rms) & (cal.residual_rms > 0), cal.residual_rms, cal.sigma_mm)
    ident = identifiability(dataset.layout, cal.layout, cal.theta, obs, sigma, target)
    return CalibrationReport(cal, dataset, ident, dict(sources or {}))


def batch_convergence(nominal: SensorLayout, obs: Observations, method: str = DEFAULT_METHOD, start: int = MIN_READINGS):
    """Estimates after the first k poses, k = start..p: the convergence of a batch method.

    Returns
    -------
    list, per sensor, of (k (q,) int, theta (q, 5) float mm/rad, stderr (q, 5) float mm/rad)
        ``k`` counts the poses used (all sensors share the pose prefix).
    """
    p = obs.n_poses
    ks, th, se = [], [], []
    for k in range(start, p + 1):
        sub = obs.select(np.arange(k))
        if np.any(np.isfinite(sub.d).sum(axis=0) < MIN_READINGS):
            continue
        cal = calibrate(nominal, sub, method)
        ks.append(k)
        th.append(cal.theta)
        se.append(cal.stderr)
    th, se = np.array(th).reshape(-1, nominal.n, 5), np.array(se).reshape(-1, nominal.n, 5)
    return [(np.array(ks), th[:, i], se[:, i]) for i in range(nominal.n)]


def residual_table(layout: SensorLayout, obs: Observations):
    """Residuals of the readings under ``layout`` and where they occur.

    Returns
    -------
    residual : (p, n) float, mm, measured - predicted; NaN where no reading
    incidence_deg : (p, n) float, deg, angle between the beam and the datum normal
    """
    pred, _ = readings(layout.zero, layout.direction, obs.normal, obs.offset)
    cos = np.abs(obs.normal @ layout.direction.T)
    return obs.d - pred, np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)))
