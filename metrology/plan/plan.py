"""``plan_poses``: the calibration poses to take, before any data exist, with their predictions.

See :mod:`metrology.plan.design` for the criterion and the search, and
:mod:`metrology.plan.candidates` for the poses and their limits. The result compares the plan
with the same number of random poses of the paper's kind under the same limits (the first
feasible candidates, drawn before any choice), and says how both fare when the robot lands
``robot_error_mm`` and ``robot_error_rad`` away from every pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from metrology.calibration.identifiability import CHART_NAMES
from metrology.calibration.uncertainty import normal_sensitivity, normal_sigma
from metrology.core.layout import SensorLayout
from metrology.core.plane import Plane
from metrology.plan.candidates import (Limits, PoseSet, draw_candidates, feasible, perturb, pose_readings,
                                       reading_bounds)
from metrology.plan.design import (EXTRA_COLUMNS, covariance, exchange, greedy_order, log_det, pose_information,
                                   prior_information)
from metrology.plan.extent import DatumExtent

__all__ = ["Design", "PosePlan", "plan_poses", "design_for", "design_columns", "CRITERION", "SEPARABLE"]

#: causes a plan can be asked to separate from the sensor parameters (``--separate``)
SEPARABLE = ("incidence", "scale", "nonlinearity")


def design_columns(separate) -> tuple:
    """The extra design columns per sensor (:data:`metrology.plan.design.EXTRA_COLUMNS`) that
    separating the causes ``separate`` takes: ``scale`` the gain, ``nonlinearity`` the gain and
    the curve, ``incidence`` its own and the whole characteristic (gain and curve).

    On a canted beam the reading and the incidence angle both follow the tilt (tilting toward
    the beam moves its zero point by the lever ``r sin(tilt)`` and turns the angle), so a plan
    that spreads incidence angles alone leaves ``c tan^2(gamma)`` nearly collinear with a
    smooth function of the reading (on the paper's Table 6 head, 100 poses at 20 deg: the
    standard error of ``c`` given the gain and curve is twice what it is given the gain
    alone), and ``diagnose`` then names the characteristic for an incidence bias."""
    want = set(separate)
    if "incidence" in want or "nonlinearity" in want:
        want |= {"scale", "nonlinearity"} if "incidence" in want else {"scale"}
    return tuple(c for c in EXTRA_COLUMNS if c in want)


#: the design criterion, in words (for reports)
CRITERION = ("Bayesian D-optimality: maximise sum over sensors of log det of the information on the five "
             "identifiable parameters (x, y, z, tilt_e1, tilt_e2; the direction's scale is the gauge) plus the "
             "filters' prior")


@dataclass(frozen=True)
class Design:
    """A pose set and what it predicts.

    Attributes
    ----------
    label : str, "planned" or "random"
    poses : PoseSet, in the order to take them
    stderr : (n, 5 + e) float, mm (x, y, z), rad (tilt_e1, tilt_e2), then the extra columns
        (:func:`design_columns`): the incidence coefficient (mm), the gain (unitless), the
        curve's c2, c3 (mm), data only
    normal_sigma_rad : float, rad, predicted 1-sigma of the measured normal at the working stand-off
    log_det : float, the criterion (:func:`metrology.plan.design.log_det`)
    curve : dict of (k,) arrays: ``k``, ``normal_sigma_rad``, ``zero_sigma_max_mm``,
        ``tilt_sigma_max_rad``, ``log_det``; inf where k poses do not determine every parameter
    reading_span_mm : (n, 2) float, mm, nominal readings' min and max per sensor
    robustness : dict, the criterion and feasibility under robot error (see :func:`plan_poses`)
    """

    label: str
    poses: PoseSet
    stderr: np.ndarray
    normal_sigma_rad: float
    log_det: float
    curve: dict
    reading_span_mm: np.ndarray
    robustness: dict = field(default_factory=dict)
    columns: tuple = ()

    def _extra_stderr(self, i) -> dict:
        names = [k for c in self.columns for k, _ in EXTRA_COLUMNS[c]]
        return {k: float(self.stderr[i, 5 + j]) for j, k in enumerate(names)}

    def to_dict(self, names) -> dict:
        inf_none = lambda a: [None if not np.isfinite(v) else float(v) for v in np.asarray(a, float)]  # noqa: E731
        return {
            "label": self.label, "n_poses": len(self.poses), "log_det": self.log_det,
            "normal_sigma_deg": float(np.rad2deg(self.normal_sigma_rad)),
            "tilt_max_deg": float(np.rad2deg(self.poses.tilt.max())),
            "standoff_span_mm": [float(self.poses.standoff.min()), float(self.poses.standoff.max())],
            "sensors": [{"name": nm, "reading_span_mm": self.reading_span_mm[i].tolist(),
                         "stderr": {"zero_mm": self.stderr[i, :3].tolist(),
                                    "tilt_deg": np.rad2deg(self.stderr[i, 3:5]).tolist(),
                                    **self._extra_stderr(i)},
                         "parameters": list(CHART_NAMES)} for i, nm in enumerate(names)],
            "curve": {"k": self.curve["k"].tolist(),
                      "normal_sigma_deg": inf_none(np.rad2deg(self.curve["normal_sigma_rad"])),
                      "zero_sigma_max_mm": inf_none(self.curve["zero_sigma_max_mm"]),
                      "tilt_sigma_max_deg": inf_none(np.rad2deg(self.curve["tilt_sigma_max_rad"])),
                      "log_det": inf_none(self.curve["log_det"])},
            "robustness": self.robustness,
        }


@dataclass(frozen=True)
class PosePlan:
    """The planned poses, the random comparison and how they were made.

    Attributes
    ----------
    layout : SensorLayout, nominal; plane : Plane, tracker frame; extent : DatumExtent
    limits : Limits; sigma_mm : (n,) float, mm; working_standoff_mm : float, mm
    n_candidates, n_feasible : int; seed : int or None
    planned, random : Design
    tolerance_cost : dict or None, what planning against the layout tolerance costs (None without
        one): ``feasible_without`` candidates feasible on the nominal layout alone, ``margin_mm_max``
        the largest distance a planned reading may move on a layout within the tolerance (the
        margin kept on top of ``reading_margin_mm``), ``normal_sigma_deg_without`` the predicted
        normal sigma of the plan made on the nominal layout alone (the planned one is
        ``planned.normal_sigma_rad``)
    """

    layout: SensorLayout
    plane: Plane
    extent: DatumExtent
    limits: Limits
    sigma_mm: np.ndarray
    working_standoff_mm: float
    n_candidates: int
    n_feasible: int
    seed: int | None
    planned: Design
    random: Design
    separate: tuple = ()
    tolerance_cost: dict | None = None

    @property
    def d_efficiency_random(self) -> float:
        """``(det M_random / det M_planned)^(1 / mn)`` (m parameters per sensor): the fraction of the plan's information per
        parameter that the random poses give (1 = as good)."""
        m = self.planned.stderr.shape[1]
        return float(np.exp((self.random.log_det - self.planned.log_det) / (m * self.layout.n)))

    def to_dict(self) -> dict:
        names = self.layout.names
        return {
            "criterion": CRITERION, "sensors": list(names), "noise_mm": self.sigma_mm.tolist(),
            "working_standoff_mm": self.working_standoff_mm, "limits": self.limits.to_dict(),
            "extent": self.extent.to_dict(), "candidates": self.n_candidates, "feasible_candidates": self.n_feasible,
            "separate": list(self.separate), "seed": self.seed,
            "planned": self.planned.to_dict(names), "random": self.random.to_dict(names),
            "d_efficiency_random": self.d_efficiency_random, "tolerance_cost": self.tolerance_cost,
        }


def _stderr(cov):
    return np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))


def design_for(label, layout, plane, X, idx, poses: PoseSet, G, prior, columns=()) -> Design:
    """The predictions of the poses ``idx`` (in order) of the candidates ``poses`` with rows ``X``
    (``columns``: its extra columns, :func:`design_columns`)."""
    ks, ns, zs, ts, lds = [], [], [], [], []
    for k in range(1, len(idx) + 1):
        cov = covariance(X[idx[:k]])
        se = _stderr(cov)
        ks.append(k)
        ns.append(normal_sigma(G, cov[:, :5, :5]))
        zs.append(float(se[:, :3].max()))
        ts.append(float(se[:, 3:5].max()))
        lds.append(log_det(X[idx[:k]], prior))
    cov = covariance(X[idx])
    sel = poses.select(idx)
    d, _ = pose_readings(layout, plane, sel)
    curve = {"k": np.array(ks), "normal_sigma_rad": np.array(ns), "zero_sigma_max_mm": np.array(zs),
             "tilt_sigma_max_rad": np.array(ts), "log_det": np.array(lds)}
    return Design(label, sel, _stderr(cov), normal_sigma(G, cov[:, :5, :5]), log_det(X[idx], prior), curve,
                  np.stack([np.nanmin(d, axis=0), np.nanmax(d, axis=0)], axis=1), columns=tuple(columns))


def _robustness(rng, design: Design, layout, plane, extent, limits, sigma, G, prior, error_mm, error_rad, trials):
    """The design re-evaluated where the robot may really land (``trials`` random perturbations)."""
    if trials <= 0 or (error_mm <= 0 and error_rad <= 0):
        return {}
    ok, eff, ns = [], [], []
    n = layout.n
    for _ in range(trials):
        moved = perturb(rng, design.poses, error_mm, error_rad)
        ok.append(feasible(layout, plane, extent, moved, limits, margins=False))
        Xm = pose_information(layout, *moved.plane_in_tcs(plane), sigma, design.columns)
        eff.append(np.exp((log_det(Xm, prior) - design.log_det) / (prior.shape[-1] * n)))
        ns.append(normal_sigma(G, covariance(Xm)[:, :5, :5]))
    ok = np.array(ok)
    return {"robot_error_mm": float(error_mm), "robot_error_deg": float(np.rad2deg(error_rad)), "trials": int(trials),
            "feasible_fraction": float(ok.mean()), "poses_ever_infeasible": int(np.sum(~ok.all(axis=0))),
            "d_efficiency_min": float(np.min(eff)), "d_efficiency_max": float(np.max(eff)),
            "normal_sigma_deg_max": float(np.rad2deg(np.max(ns)))}


def plan_poses(layout: SensorLayout, plane: Plane, extent: DatumExtent, n_poses: int, limits: Limits, sigma_mm,
               rng: np.random.Generator, working_standoff_mm=None, n_candidates: int = 5000,
               robot_error_mm: float = 1.0, robot_error_rad: float = float(np.deg2rad(0.1)),
               robustness_trials: int = 20, seed=None, separate=()) -> PosePlan:
    """Choose ``n_poses`` calibration poses (D-optimal, greedy order, Fedorov exchanges).

    Parameters
    ----------
    layout : SensorLayout, the nominal layout (where the design is linearised)
    plane : Plane, tracker frame; extent : DatumExtent, the measured datum
    n_poses : int, at least 5
    limits : Limits
    sigma_mm : float or (n,) float, mm, reading noise (1 sigma)
    rng : numpy.random.Generator, draws the candidates, then the robot errors
    working_standoff_mm : float, mm, where the normal's sigma is predicted (default: the middle
        of ``limits.standoff_mm``)
    n_candidates : int, random poses drawn to choose from
    robot_error_mm, robot_error_rad : how far from a planned pose the robot may land (mm, rad);
        the designs are re-evaluated ``robustness_trials`` times with every pose moved that much
    seed : int, optional, recorded in the result
    separate : tuple of str, causes the design must also tell from the sensor parameters:
        ``("incidence",)`` adds each sensor's incidence coefficient, gain and curve to the
        D-criterion, ``("scale",)`` the gain alone (:func:`design_columns`)

    Returns
    -------
    PosePlan
    """
    unknown = [c for c in separate if c not in SEPARABLE]
    if unknown:
        raise ValueError(f"--separate {', '.join(unknown)}: expected one of {', '.join(SEPARABLE)}")
    inc = design_columns(separate)
    if n_poses < 5:
        raise ValueError(f"--poses {n_poses}: need at least 5 (5 parameters per sensor)")
    sigma = np.broadcast_to(np.asarray(sigma_mm, float), (layout.n,)).copy()
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ValueError(f"reading noise {sigma.tolist()} mm: expected positive numbers (noise_mm in the layout)")
    if not np.all(np.isfinite(limits.range_mm)):
        raise ValueError("every sensor needs a range (range_mm in the layout): the plan keeps readings inside it")
    work = float(np.mean(limits.standoff_mm)) if working_standoff_mm is None else float(working_standoff_mm)
    cands = draw_candidates(rng, layout, plane, extent, n_candidates, limits)
    pool = np.flatnonzero(feasible(layout, plane, extent, cands, limits))
    if len(pool) < n_poses:
        raise ValueError(f"only {len(pool)} of {n_candidates} candidate poses keep every limit (extent, range with "
                         f"{limits.reading_margin_mm:g} mm margin{_tol_words(limits)}, tilt, stand-off {limits.standoff_mm}); need "
                         f"{n_poses}: widen the stand-off or tilt limits, or draw more candidates"
                         + ("; none at all: is the tool on the other side of the datum (--tool-side)?" if not len(pool) else ""))
    X = pose_information(layout, *cands.plane_in_tcs(plane), sigma, inc)
    prior = prior_information(layout.n, incidence=inc)
    chosen = exchange(X, greedy_order(X, n_poses, prior, pool), prior, pool)
    order = chosen[greedy_order(X[chosen], n_poses, prior)]
    G = normal_sensitivity(layout, work)
    planned = design_for("planned", layout, plane, X, order, cands, G, prior, inc)
    random = design_for("random", layout, plane, X, pool[:n_poses], cands, G, prior, inc)
    cost = None
    if limits.zero_tol_mm > 0 or limits.direction_tol_rad > 0:
        cost = _tolerance_cost(layout, plane, extent, limits, cands, X, prior, planned, n_poses, G, inc, len(pool))
    args = (layout, plane, extent, limits, sigma, G, prior, robot_error_mm, robot_error_rad, robustness_trials)
    planned = replace(planned, robustness=_robustness(rng, planned, *args))
    random = replace(random, robustness=_robustness(rng, random, *args))
    return PosePlan(layout, plane, extent, limits, sigma, work, n_candidates, len(pool), seed, planned, random,
                    tuple(separate), cost)


def _tol_words(limits) -> str:
    if limits.zero_tol_mm == 0 and limits.direction_tol_rad == 0:
        return ""
    return (f" on every layout within {limits.zero_tol_mm:g} mm and {np.rad2deg(limits.direction_tol_rad):g} deg of the "
            "nominal (the layout tolerance)")


def _tolerance_cost(layout, plane, extent, limits, cands, X, prior, planned: Design, n_poses, G, inc, n_feasible) -> dict:
    """What planning against the layout tolerance costs (:attr:`PosePlan.tolerance_cost`): the same
    candidates planned on the nominal layout alone, and the margin the tolerance keeps."""
    nominal = replace(limits, zero_tol_mm=0.0, direction_tol_rad=0.0)
    pool = np.flatnonzero(feasible(layout, plane, extent, cands, nominal))
    chosen = exchange(X, greedy_order(X, n_poses, prior, pool), prior, pool)
    without = design_for("planned", layout, plane, X, chosen, cands, G, prior, inc)
    d, _ = pose_readings(layout, plane, planned.poses)
    d_lo, d_hi, _ = reading_bounds(layout, plane, planned.poses, limits.zero_tol_mm, limits.direction_tol_rad)
    return {"zero_mm": limits.zero_tol_mm, "direction_deg": float(np.rad2deg(limits.direction_tol_rad)),
            "feasible": int(n_feasible), "feasible_without": int(len(pool)), "margin_mm_max": float(np.max(np.maximum(d_hi - d, d - d_lo))),
            "normal_sigma_deg_without": float(np.rad2deg(without.normal_sigma_rad)),
            "normal_sigma_deg": float(np.rad2deg(planned.normal_sigma_rad))}
