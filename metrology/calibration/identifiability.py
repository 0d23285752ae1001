"""Identifiability of the five parameters per sensor: what the poses determine, what they leave weak, and the pose spread that would fix it."""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np
from metrology.calibration.dataset import MIN_READINGS
from metrology.core.observations import Observations
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, jacobian_raw, jacobian_tangent, readings
from metrology.core.tolerances import RANK_RTOL, WEAK_RTOL
from metrology.core.tolerances import TARGET_TILT_DEG, TARGET_ZERO_MM, VIF_WARN


#: names of the chart parameters as reported: zero point (mm, TCS) and beam tilt about the
#: chart axes e1, e2 (rad inside, deg in reports)
CHART_NAMES = ("x", "y", "z", "tilt_e1", "tilt_e2")


#: synthetic pose sets scanned for the "what would fix it" advice: maximum tilt (deg) and
#: spread of the stand-off along the datum normal (mm)
_TILT_SCAN_DEG = (2.0, 3.0, 5.0, 8.0, 10.0, 15.0, 20.0, 30.0)


_STANDOFF_SCAN_MM = (0.0, 5.0, 10.0, 20.0, 30.0, 40.0, 60.0)


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
                                f"{sigma_words(comb_sigma[-1])}, which moves the measured normal by "
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


def sigma_words(v):
    """``v`` (5,) float, mm/rad, a chart-parameter vector, as "<zero norm> mm and <tilt norm> deg"."""
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
