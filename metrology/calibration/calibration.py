"""Calibration and validation from measured files: what ``metro calibrate`` and ``validate`` do.

``calibrate_dataset``
    Runs an estimator of :mod:`metrology.calibration.estimators` on a :class:`~metrology.dataset.Dataset`
    and reports, per sensor, the nominal, estimated and corrected parameters with standard
    errors, the residual RMS, the correlations above :data:`CORRELATION_REPORT` and the
    identifiability of the parameters from this pose set.
``identifiability``
    Per sensor, the singular values of the stacked, column-scaled Jacobian, for the paper's
    six raw parameters (whose null direction is the gauge, the direction scale) and for the
    five-parameter chart ``(x, y, z, tilt_e1, tilt_e2)``; the least-determined
    combinations named in words; variance inflation factors; and, when a parameter is
    poorly excited, the pose spread (tilt, stand-off) that would fix it, found by
    recomputing the predicted standard errors on synthetic pose sets, not guessed.
``validate``
    Per pose, the micro-plane normal the sensors measure (Eqs. 17-19, least-squares plane
    when a reading is missing) against the datum normal expressed in the TCS, for one or
    more layouts side by side (Tables 4 and 8, Figure 12).

Units: mm and rad inside; results expose degrees only in fields named ``*_deg``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.calibration.dataset import MIN_READINGS, Dataset, check
from metrology.calibration.estimators import METHODS, Calibration, Observations, calibrate
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, jacobian_raw, jacobian_tangent, readings
from metrology.core.tolerances import RANK_RTOL, WEAK_RTOL

__all__ = [
    "DEFAULT_METHOD",
    "CORRELATION_REPORT",
    "VIF_WARN",
    "TARGET_ZERO_MM",
    "TARGET_TILT_DEG",
    "CHART_NAMES",
    "CalibrationReport",
    "Identifiability",
    "ValidationReport",
    "calibrate_dataset",
    "identifiability",
    "describe_combination",
    "batch_convergence",
    "residual_table",
    "validate",
    "calibrate_files",
    "validate_files",
]

from metrology.core.tolerances import CORRELATION_REPORT, TARGET_TILT_DEG, TARGET_ZERO_MM, VIF_WARN  # noqa: F401
from metrology.core.paper import EKF_PRESETS

#: the default estimator: on fixtures/measured, lsq and iekf recover the truth equally
#: well (README "Estimators compared"); lsq is the fastest and its standard errors are
#: scaled by the residual, so they stay honest when the stated noise is optimistic
DEFAULT_METHOD = "lsq"

#: names of the chart parameters as reported: zero point (mm, TCS) and beam tilt about the
#: chart axes e1, e2 (rad inside, deg in reports)
CHART_NAMES = ("x", "y", "z", "tilt_e1", "tilt_e2")

#: the paper's EKF runs with the experiment's settings (section 6) unless told otherwise
_METHOD_DEFAULTS = {"ekf_paper": EKF_PRESETS["experiment"]}

#: synthetic pose sets scanned for the "what would fix it" advice: maximum tilt (deg) and
#: spread of the stand-off along the datum normal (mm)
_TILT_SCAN_DEG = (2.0, 3.0, 5.0, 8.0, 10.0, 15.0, 20.0, 30.0)
_STANDOFF_SCAN_MM = (0.0, 5.0, 10.0, 20.0, 30.0, 40.0, 60.0)


# ---------------------------------------------------------------------------------------
# identifiability


def _column_scaled_svd(J):
    """Singular values and right vectors of ``J`` with unit-norm columns; return scales too."""
    scale = np.linalg.norm(J, axis=0)
    safe = np.where(scale > 0, scale, 1.0)
    _, s, vt = np.linalg.svd(J / safe, full_matrices=False)
    return s, vt, safe


def _vif(J):
    """Variance inflation factors (k,) of the columns of ``J (m, k)`` (inf: not determined)."""
    scale = np.linalg.norm(J, axis=0)
    if np.any(scale == 0):
        out = np.full(J.shape[1], np.inf)
        return out
    Js = J / scale
    s = np.linalg.svd(Js, compute_uv=False)
    if s[-1] <= RANK_RTOL * s[0]:
        return np.full(J.shape[1], np.inf)
    return np.einsum("ii->i", np.linalg.inv(Js.T @ Js))


def _tcs_words(v):
    """'+y' style name of the TCS axis closest to unit vector ``v`` (3,), with the vector."""
    k = int(np.argmax(np.abs(v)))
    return f"{'+' if v[k] >= 0 else '-'}{'xyz'[k]} (TCS {np.round(v, 2).tolist()})"


def describe_combination(v, u, basis, mean_reading):
    """Name a chart-parameter combination in words.

    Parameters
    ----------
    v : (5,) float
        Change of ``(x, y, z)`` mm and ``(tilt_e1, tilt_e2)`` rad (any overall scale).
    u : (3,) float, unit, TCS
        The beam direction.
    basis : (2, 3) float, TCS
        Chart axes e1, e2 of this sensor.
    mean_reading : float, mm
        Mean reading of this sensor over the poses (to compare tilts with shifts: a tilt
        ``t`` moves the spot by ``mean_reading * t`` mm).

    Returns
    -------
    words : str
    pivot_mm : float or None
        For a pivot (lateral zero traded against tilt), the distance along the beam from
        the zero point to the pivot, mm.
    """
    dE = np.asarray(v[:3], float)
    du = basis.T @ np.asarray(v[3:], float)
    along = float(dE @ u)
    lat = dE - along * u
    size = {"along": abs(along), "lat": np.linalg.norm(lat), "tilt": mean_reading * np.linalg.norm(du)}
    top = max(size.values())
    sig = {k for k, s in size.items() if s > 0.2 * top}
    if {"lat", "tilt"} <= sig and np.linalg.norm(du) > 0:
        t = -float(lat @ du) / float(du @ du)
        miss = np.linalg.norm(lat + t * du)
        if miss < 0.3 * size["lat"]:
            words = (f"pivot of the beam about the point {t:.1f} mm along it (mean reading {mean_reading:.1f} mm): "
                     f"zero point across the beam, towards {_tcs_words(lat / size['lat'])}, traded against "
                     "beam tilt")
            if "along" in sig:
                words += ", with the zero point along the beam"
            return words, t
    parts = []
    if "along" in sig:
        parts.append("zero point along the beam")
    if "lat" in sig:
        parts.append(f"zero point across the beam, towards {_tcs_words(lat / size['lat'])}")
    if "tilt" in sig:
        parts.append(f"beam tilt towards {_tcs_words(du / np.linalg.norm(du))}")
    return " with ".join(parts), None


def _synthetic_planes(normal, offset, spots, tilt, spread):
    """Deterministic pose set: the mean datum in TCS tilted up to ``tilt`` rad in every
    direction (stratified, golden-angle azimuths) and shifted along its normal over
    ``spread`` mm, through the mean spot centroid. Returns normals (m, 3), offsets (m,)."""
    m = len(offset)
    nbar = normal.mean(axis=0)
    nbar /= np.linalg.norm(nbar)
    cbar = spots.mean(axis=0)
    e = direction_basis(nbar[None])[0]
    k = np.arange(m)
    alpha = tilt * np.sqrt((k + 0.5) / m)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    n_new = (np.cos(alpha)[:, None] * nbar + np.sin(alpha)[:, None]
             * (np.cos(phi)[:, None] * e[0] + np.sin(phi)[:, None] * e[1]))
    h = spread * (((k * 7) % m + 0.5) / m - 0.5)  # stand-off stratified, decorrelated from tilt
    points = cbar + h[:, None] * nbar
    return n_new, -np.sum(n_new * points, axis=1)


@dataclass(frozen=True)
class Identifiability:
    """How well one sensor's parameters are determined by a pose set.

    Attributes
    ----------
    name : str
    n_readings : int
    raw_singular : (6,) float, relative (largest = 1), column-scaled raw Jacobian
    raw_null_words : str
        The raw null direction in words (the gauge: the direction scale).
    raw_gauge_cos : float
        |cos| between the raw null direction and ``(0, 0, 0, u)`` (1: it is the gauge).
    chart_singular : (5,) float, relative, column-scaled chart Jacobian
    chart_condition : float
    chart_vectors : (5, 5) float
        Right singular vectors, rows, in physical units (mm, rad), unit norm.
    combination_sigma : (5,) list of (5,) float
        Predicted 1-sigma change of each combination in physical units (mm, rad).
    words : list of str, per singular vector
    normal_effect : (5,) float, rad
        RMS over the poses of the error of the measured normal if the sensor were really
        off its estimate by one sigma of that combination.
    vif : (5,) float, variance inflation factors of the chart parameters
    predicted_stderr : (5,) float, mm and rad, with the noise ``sigma_mm``
    sigma_mm : float, mm
    reading_span_mm : (2,) float, mm, min and max reading
    tilt_max_deg : float, deg, largest angle between a pose's datum normal and the mean
    standoff_spread_mm : float, mm, spread of the mean spot along the datum normal
    fix : dict
        When a predicted standard error exceeds the target: the smallest synthetic pose
        spread (tilt in every direction, stand-off) that meets it with the same number of
        poses, within the sensor range and ignoring it, and the number of poses that would
        meet it at the current spread (empty when the target is met).
    warnings : list of str
    """

    name: str
    n_readings: int
    raw_singular: np.ndarray
    raw_null_words: str
    raw_gauge_cos: float
    chart_singular: np.ndarray
    chart_condition: float
    chart_vectors: np.ndarray
    combination_sigma: np.ndarray
    words: list
    normal_effect: np.ndarray
    vif: np.ndarray
    predicted_stderr: np.ndarray
    sigma_mm: float
    reading_span_mm: np.ndarray
    tilt_max_deg: float
    standoff_spread_mm: float
    fix: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def to_dict(self) -> dict:
        rel = self.chart_singular
        status = ["unidentifiable" if r <= RANK_RTOL else "weak" if r <= WEAK_RTOL else "ok" for r in rel]
        combos = []
        for k in range(len(rel)):
            vec = self.chart_vectors[k]
            combos.append({
                "relative_singular_value": rel[k],
                "status": status[k],
                "vector": dict(zip(CHART_NAMES, vec)),
                "sigma": {"zero_mm": self.combination_sigma[k][:3], "tilt_deg": np.rad2deg(self.combination_sigma[k][3:])},
                "words": self.words[k],
                "normal_effect_deg": np.rad2deg(self.normal_effect[k]),
            })
        return {
            "name": self.name,
            "n_readings": self.n_readings,
            "raw": {"parameters": ["x", "y", "z", "m", "n", "q"], "relative_singular_values": self.raw_singular,
                    "null_direction": self.raw_null_words, "gauge_cos": self.raw_gauge_cos},
            "chart": {"parameters": list(CHART_NAMES), "relative_singular_values": rel,
                      "condition": self.chart_condition, "combinations": combos,
                      "vif": dict(zip(CHART_NAMES, self.vif)),
                      "poorly_separated": [CHART_NAMES[j] for j in range(5) if not self.vif[j] <= VIF_WARN],
                      "predicted_stderr": {"zero_mm": self.predicted_stderr[:3],
                                           "tilt_deg": np.rad2deg(self.predicted_stderr[3:])}},
            "pose_spread": {"reading_min_mm": self.reading_span_mm[0], "reading_max_mm": self.reading_span_mm[1],
                            "tilt_max_deg": self.tilt_max_deg, "standoff_spread_mm": self.standoff_spread_mm},
            "fix": self.fix,
            "warnings": self.warnings,
        }


def _pose_spread(obs: Observations, spots):
    nbar = obs.normal.mean(axis=0)
    nbar /= np.linalg.norm(nbar)
    tilt = np.arccos(np.clip(obs.normal @ nbar, -1.0, 1.0))
    h = (spots - spots.mean(axis=0)) @ nbar
    return float(np.rad2deg(tilt.max())), float(h.max() - h.min()) if len(h) else 0.0


def _spots(layout: SensorLayout, obs: Observations):
    """(p, 3) mm TCS: centroid of the predicted spots of all sensors on each pose's datum."""
    d, _ = readings(layout.zero, layout.direction, obs.normal, obs.offset)
    S = layout.zero[None] + d[..., None] * layout.direction[None]
    return np.nanmean(S, axis=1)


def _chart_J(layout, nominal, theta_i, i, N, D):
    return jacobian_tangent(layout.zero[i][None], nominal.direction[i][None], theta_i[None, 3:], N, D)[:, 0, :]


def _meets(pse, target):
    return bool(np.all(pse[:3] <= target[0]) and np.all(pse[3:] <= target[1]))


def _find_fix(layout, nominal, theta_i, i, obs, spots, sigma, target, respect_range):
    """Smallest (tilt, stand-off spread) in the scan whose predicted standard errors meet
    ``target`` (mm, rad) with the same number of poses; None if none does."""
    lo, hi = layout.range_mm[i]
    m = obs.n_poses
    for tilt_deg in _TILT_SCAN_DEG:
        for spread in _STANDOFF_SCAN_MM:
            N, D = _synthetic_planes(obs.normal, obs.offset, spots, np.deg2rad(tilt_deg), spread)
            d, valid = readings(layout.zero[i][None], layout.direction[i][None], N, D)
            ok = valid[:, 0]
            if respect_range:
                ok &= (d[:, 0] >= lo) & (d[:, 0] <= hi)
            if ok.sum() < max(MIN_READINGS, m // 2):
                continue
            pse = _predicted_stderr(_chart_J(layout, nominal, theta_i, i, N[ok], D[ok]), sigma)
            if _meets(pse, target):
                return {"tilt_max_deg": tilt_deg, "standoff_spread_mm": spread, "readings": int(ok.sum()),
                        "reading_span_mm": [float(np.min(d[ok, 0])), float(np.max(d[ok, 0]))],
                        "predicted_stderr": {"zero_mm": pse[:3], "tilt_deg": np.rad2deg(pse[3:])}}
    return None


def _predicted_stderr(J, sigma):
    """(5,) mm/rad: 1-sigma of the chart parameters from ``J (m, 5)`` and noise ``sigma`` mm."""
    s = np.linalg.svd(J / np.maximum(np.linalg.norm(J, axis=0), 1e-300), compute_uv=False)
    if s[-1] <= RANK_RTOL * s[0]:
        return np.full(5, np.inf)
    return sigma * np.sqrt(np.maximum(np.diag(np.linalg.inv(J.T @ J)), 0.0))


def _normal_effect(nominal, layout, theta_i, i, dtheta, obs):
    """RMS over the poses (rad) of the error of the measured normal when sensor ``i`` is
    really off its estimate ``theta_i`` (5,) by ``dtheta`` (5,) mm/rad (chart around the
    nominal direction) and the others are exact."""
    from metrology.core.model import direction_from_tangent
    from metrology.core.normals import angle_between, micro_plane_normal

    d, _ = readings(layout.zero, layout.direction, obs.normal, obs.offset)
    u_true = direction_from_tangent(nominal.direction[i][None], (theta_i[3:] + dtheta[3:])[None])
    di, _ = readings(layout.zero[i][None] + dtheta[:3], u_true, obs.normal, obs.offset)
    d = d.copy()
    d[:, i] = di[:, 0]
    ang = angle_between(micro_plane_normal(layout.zero, layout.direction, d), obs.normal)
    ang = ang[np.isfinite(ang)]
    return float(np.sqrt(np.mean(ang**2))) if len(ang) else float("nan")


def identifiability(nominal: SensorLayout, layout: SensorLayout, theta, obs: Observations, sigma_mm,
                    target=None) -> list:
    """Identifiability of every sensor's parameters from the poses of ``obs``.

    Parameters
    ----------
    nominal : SensorLayout
        The chart centres (nominal directions).
    layout : SensorLayout
        Where to linearise (the estimate).
    theta : (n, 5) float, mm and rad
        Chart coordinates of ``layout`` around ``nominal``.
    obs : Observations
    sigma_mm : (n,) float, mm
        Reading noise used for the predicted standard errors.
    target : (float, float), optional
        Wanted 1-sigma of the zero point (mm) and of the beam tilt (rad); default
        :data:`TARGET_ZERO_MM`, :data:`TARGET_TILT_DEG`. A parameter above it is flagged and
        a pose spread that would meet it is searched for.

    Returns
    -------
    list of Identifiability, one per sensor
    """
    target = (TARGET_ZERO_MM, np.deg2rad(TARGET_TILT_DEG)) if target is None else tuple(map(float, target))
    theta = np.asarray(theta, float)
    spots = _spots(layout, obs)
    tilt_max_deg, spread = _pose_spread(obs, spots)
    basis_all = direction_basis(nominal.direction)
    out = []
    for i, name in enumerate(layout.names):
        rows = np.flatnonzero(np.isfinite(obs.d[:, i]))
        N, D = obs.normal[rows], obs.offset[rows]
        u = layout.direction[i]
        # raw six parameters: the gauge
        J6 = jacobian_raw(layout.zero[i][None], u[None], N, D)[:, 0, :]
        s6, vt6, c6 = _column_scaled_svd(J6)
        null = vt6[-1] / c6
        null /= np.linalg.norm(null)
        gauge = np.concatenate([np.zeros(3), u])
        gauge_cos = float(abs(null @ gauge))
        raw_words = ("direction scale (gauge): readings do not depend on |u|" if gauge_cos > 0.99
                     else "not the gauge: " + ", ".join(f"{p} {c:+.2f}" for p, c in zip("xyzmnq", null)))
        # the five-parameter chart
        J = _chart_J(layout, nominal, theta[i], i, N, D)
        s, vt, c = _column_scaled_svd(J)
        rel = s / s[0]
        cond = float(s[0] / s[-1]) if s[-1] > 0 else np.inf
        vecs = vt / c
        vecs /= np.linalg.norm(vecs, axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            comb_sigma = (sigma_mm[i] / s)[:, None] * (vt / c)
        dmean = float(np.mean(obs.d[rows, i]))
        words = [describe_combination(vecs[k], u, basis_all[i], dmean)[0] for k in range(5)]
        effect = np.array([_normal_effect(nominal, layout, theta[i], i, comb_sigma[k], obs) if np.all(np.isfinite(comb_sigma[k]))
                           else np.inf for k in range(5)])
        vif = _vif(J)
        pse = _predicted_stderr(J, sigma_mm[i])
        warnings = []
        for k in range(5):
            if rel[k] <= RANK_RTOL:
                warnings.append(f"{name}: not determined by these poses: {words[k]} "
                                f"(relative singular value {rel[k]:.1e})")
            elif rel[k] <= WEAK_RTOL:
                warnings.append(f"{name}: weakly determined: {words[k]} (relative singular value {rel[k]:.1e})")
        fix = {}
        if not _meets(pse, target):
            bad = [f"{CHART_NAMES[j]} {pse[j]:.3g} mm" for j in range(3) if not pse[j] <= target[0]]
            bad += [f"{CHART_NAMES[j]} {np.rad2deg(pse[j]):.3g} deg" for j in range(3, 5) if not pse[j] <= target[1]]
            if np.all(np.isfinite(pse)):
                warnings.append(f"{name}: 1 sigma above target ({target[0]:g} mm, {np.rad2deg(target[1]):g} deg): "
                                f"{', '.join(bad)}; least determined: {words[-1]}, 1 sigma "
                                f"{_sigma_words(comb_sigma[-1])}, which moves the measured normal by "
                                f"{np.rad2deg(effect[-1]):.2g} deg RMS")
            in_range = _find_fix(layout, nominal, theta[i], i, obs, spots, sigma_mm[i], target, True)
            free = _find_fix(layout, nominal, theta[i], i, obs, spots, sigma_mm[i], target, False)
            ratio = np.max(np.concatenate([pse[:3] / target[0], pse[3:] / target[1]]))
            more = int(np.ceil(obs.n_poses * ratio**2)) if np.isfinite(ratio) else None
            fix = {"target": {"zero_mm": target[0], "tilt_deg": np.rad2deg(target[1])}, "n_poses": obs.n_poses,
                   "within_range": in_range, "ignoring_range": free, "poses_needed_at_current_spread": more}
            warnings.append(f"{name}: {_fix_words(fix, layout.range_mm[i], tilt_max_deg, spread)}")
        out.append(Identifiability(
            name, int(len(rows)), s6 / s6[0], raw_words, gauge_cos, rel, cond, vecs, comb_sigma, words, effect, vif,
            pse, float(sigma_mm[i]), np.array([np.min(obs.d[rows, i]), np.max(obs.d[rows, i])]), tilt_max_deg,
            spread, fix, warnings))
    return out


def _sigma_words(v):
    return f"{np.linalg.norm(v[:3]):.3g} mm and {np.rad2deg(np.linalg.norm(v[3:])):.3g} deg"


def _fix_words(fix, rng_mm, tilt_now, spread_now):
    now = f"now: tilt up to {tilt_now:.1f} deg, stand-off spread {spread_now:.1f} mm, {fix['n_poses']} poses"
    a, b, more = fix["within_range"], fix["ignoring_range"], fix["poses_needed_at_current_spread"]
    alt = f"; or about {more} poses with the current spread" if more is not None else ""
    if a is not None:
        return (f"poses tilted up to {a['tilt_max_deg']:g} deg in every direction with a stand-off spread of "
                f"{a['standoff_spread_mm']:g} mm would meet the target within the sensor range{alt} ({now})")
    if b is not None:
        return (f"no pose set within the sensor range [{rng_mm[0]:g}, {rng_mm[1]:g}] mm meets the target; it would take "
                f"tilts up to {b['tilt_max_deg']:g} deg and a stand-off spread of {b['standoff_spread_mm']:g} mm "
                f"(readings {b['reading_span_mm'][0]:.0f}-{b['reading_span_mm'][1]:.0f} mm){alt} ({now})")
    return (f"no scanned pose set (tilt up to {_TILT_SCAN_DEG[-1]:g} deg, stand-off spread up to "
            f"{_STANDOFF_SCAN_MM[-1]:g} mm) meets the target{alt} ({now})")


# ---------------------------------------------------------------------------------------
# calibration report


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


# ---------------------------------------------------------------------------------------
# data for the plots


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


# ---------------------------------------------------------------------------------------
# validation


@dataclass(frozen=True)
class ValidationReport:
    """Angular deviation of the measured normal from the datum normal, per layout.

    Attributes
    ----------
    pose_id : tuple of str, length p
    labels : tuple of str, one per layout
    deviation : (k, p) float, rad; NaN where fewer than 3 readings
    n_readings : (p,) int, readings per pose
    n_sensors : int
    sources : dict
    """

    pose_id: tuple
    labels: tuple
    deviation: np.ndarray
    n_readings: np.ndarray
    n_sensors: int
    sources: dict = field(default_factory=dict)

    def stats_deg(self, k: int) -> dict:
        """max / mean / std (sample, ddof=1) of the deviation of layout ``k``, deg."""
        a = np.rad2deg(self.deviation[k])
        a = a[np.isfinite(a)]
        return {"max_deg": float(np.max(a)), "mean_deg": float(np.mean(a)),
                "std_deg": float(np.std(a, ddof=1)) if len(a) > 1 else 0.0, "n_poses": int(len(a))}

    def to_dict(self) -> dict:
        return {
            "sources": self.sources,
            "n_poses": len(self.pose_id),
            "layouts": {lab: {**self.stats_deg(k), "deviation_deg": np.rad2deg(self.deviation[k])}
                        for k, lab in enumerate(self.labels)},
            "pose_id": list(self.pose_id),
            "n_readings": self.n_readings,
        }

    def text(self) -> str:
        w = max(14, *(len(lab) for lab in self.labels))
        lines = [f"{'layout':<{w}} {'max [deg]':>10} {'mean [deg]':>10} {'std [deg]':>10} {'poses':>6}  file"]
        for k, lab in enumerate(self.labels):
            s = self.stats_deg(k)
            lines.append(f"{lab:<{w}} {s['max_deg']:10.4f} {s['mean_deg']:10.4f} {s['std_deg']:10.4f} {s['n_poses']:6d}  "
                         f"{self.sources.get(lab, '')}")
        partial = int(np.sum((self.n_readings < self.n_sensors) & (self.n_readings >= 3)))
        none = int(np.sum(self.n_readings < 3))
        if none:
            lines.append(f"{none} pose(s) with fewer than 3 readings: no normal, left out")
        if partial:
            lines.append(f"{partial} pose(s) with a missing reading: normal from the least-squares plane of the rest")
        return "\n".join(lines)


def validate(dataset: Dataset, layouts: dict, sources=None) -> ValidationReport:
    """Angular deviation of the sensors' normal from the datum normal, per pose and layout.

    Parameters
    ----------
    dataset : Dataset
        Validation poses, readings and the datum (its own layout is not used).
    layouts : dict of label -> SensorLayout
        Each is checked against the export (same sensors, readings within range).

    Returns
    -------
    ValidationReport
        The normal of each pose is Eqs. 17-19 with all four readings, or the
        least-squares plane of the projection points when a reading is missing (NaN with
        fewer than 3); compared, unoriented, with the datum normal in that pose's TCS.
    """
    from metrology.core.normals import angle_between, micro_plane_normal

    if not layouts:
        raise ValueError("validate: no layout given")
    obs = dataset.obs
    dev = []
    for label, layout in layouts.items():
        export = check(dataset.export, layout, f"layout {label}")
        n = micro_plane_normal(layout.zero, layout.direction, export.d)
        dev.append(angle_between(n, obs.normal))
    dev = np.array(dev)
    if not np.any(np.isfinite(dev[0])):
        raise ValueError("validate: no pose has 3 or more readings")
    nread = np.isfinite(dataset.export.d).sum(axis=1)
    return ValidationReport(tuple(dataset.export.pose_id), tuple(layouts), dev, nread, int(dataset.export.d.shape[1]),
                            dict(sources or {}))


# ---------------------------------------------------------------------------------------
# from files (what the CLI calls)


def calibrate_files(export_path, plane_path, layout_path, method: str = DEFAULT_METHOD, target=None, out=None,
                    plot_dir=None, **kwargs) -> CalibrationReport:
    """Load and cross-check the three files, calibrate, and write the requested outputs.

    Nothing is written unless the calibration succeeds; each file is written atomically
    (the figures first, then the calibrated layout ``out``, in the schema of the nominal
    with ``zero_stderr_mm`` and ``direction_stderr_deg`` added).
    """
    from metrology.calibration.dataset import load_dataset
    from metrology.core.layout import save_layout

    dataset = load_dataset(export_path, plane_path, layout_path)
    sources = {"export": str(export_path), "plane": str(plane_path), "layout": str(layout_path)}
    report = calibrate_dataset(dataset, method, sources=sources, target=target, **kwargs)
    if plot_dir is not None:
        from metrology.report.calibration_plots import write_calibration_plots

        write_calibration_plots(report, plot_dir)
    if out is not None:
        rms = ", ".join(f"{n} {r * 1e3:.1f} um" for n, r in zip(report.layout.names, report.calibration.residual_rms))
        save_layout(report.layout, out,
                    f"Calibrated by metro calibrate --method {method}\n"
                    f"export {export_path}, datum {plane_path}, nominal {layout_path}\n"
                    f"{dataset.export.n_poses} poses; residual RMS {rms}\n"
                    "zero_stderr_mm: 1 sigma of the zero point (mm, TCS x y z); direction_stderr_deg: 1 sigma\n"
                    "of the beam tilt about the chart axes e1, e2 of the nominal direction (deg)")
    return report


def validate_files(export_path, plane_path, layout_path, layout_before_path=None, plot=None) -> ValidationReport:
    """Validate ``layout_path`` (and ``layout_before_path``, first, if given) on an export.

    The layouts are reported under the labels ``layout_before`` and ``layout``; ``plot``
    writes the deviation per pose as a PNG (atomically).
    """
    from metrology.calibration.dataset import load_dataset
    from metrology.core.layout import load_layout

    dataset = load_dataset(export_path, plane_path, layout_path)
    layouts = {}
    sources = {"export": str(export_path), "plane": str(plane_path)}
    if layout_before_path is not None:
        layouts["layout_before"] = load_layout(layout_before_path)
        sources["layout_before"] = str(layout_before_path)
    layouts["layout"] = dataset.layout
    sources["layout"] = str(layout_path)
    report = validate(dataset, layouts, sources)
    if plot is not None:
        from metrology.report.calibration_plots import plot_validation

        plot_validation(report, plot)
    return report
