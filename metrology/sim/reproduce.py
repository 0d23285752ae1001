"""The paper's simulation (section 5, steps 1-10), reproduced and extended.

One trial:

1. the datum plane (Table 1, or Table 5 for the experiment layout) is sampled at
   ``n_datum_points`` points with isotropic tracker noise and fitted (Table 1 analogue);
2. the nominal layout and its true errors (Table 2, or Table 6 for the experiment);
3-6. ``n_poses`` calibration poses (see :mod:`metrology.sim.simulation` for the distribution),
   readings of the *true* sensors on the *true* datum plus white noise; the estimators
   only know the *fitted* datum;
7. every estimator identifies the errors;
8-10. ``n_workpiece`` poses on a workpiece plane of random orientation: the normal is
   measured (Eqs. 17-19) with the nominal, each estimated and the true parameters, and
   compared with the true normal.

Nothing here is tuned to the paper's numbers; they are shown beside ours for reference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.core.progress import notify
from metrology.core import paper
from metrology.calibration.estimators import calibrate
from metrology.core.observations import Observations
from metrology.core.normals import angle_between, micro_plane_normal
from metrology.core.plane import Plane, fit_plane_tls
from metrology.core.stats import describe
from metrology.sim.simulation import PoseSpec, datum_points, random_poses, simulate_readings

__all__ = ["ReproduceConfig", "Trial", "run_trial", "run_trials", "summarize", "METHOD_ORDER"]

#: columns of Table 4, left to right: before calibration, the estimators, the truth floor
METHOD_ORDER = ("before", "method1", "ekf_paper", "ekf", "iekf", "lsq", "true")


@dataclass(frozen=True)
class ReproduceConfig:
    """Settings of one reproduction (lengths mm, angles rad).

    ``layout`` is ``"simulation"`` (Tables 1-2, EKF Q = 1e-10, R = 8e-5) or
    ``"experiment"`` (Tables 5-6 with Table 6's estimate as the truth, Q = 1e-12, R = 9e-6).
    """

    layout: str = "simulation"
    n_datum_points: int = 20
    datum_noise_mm: float = 0.02
    datum_size_mm: float = 200.0
    n_poses: int = 100
    noise_mm: float = 0.01
    n_workpiece: int = 20
    poses: PoseSpec = field(default_factory=PoseSpec)

    def __post_init__(self):
        if self.layout not in ("simulation", "experiment"):
            raise ValueError(f"layout must be 'simulation' or 'experiment', got {self.layout!r}")
        if self.n_poses < 6 or self.n_datum_points < 3 or self.n_workpiece < 1:
            raise ValueError("need at least 6 poses, 3 datum points and 1 workpiece pose")
        if not (self.noise_mm >= 0 and self.datum_noise_mm >= 0):
            raise ValueError("noise must be >= 0 mm")

    def tables(self):
        """(nominal layout, true layout, true datum (A, B, C, D) in the paper's sign, EKF preset)."""
        if self.layout == "simulation":
            nominal, true = paper.table2_layouts()
            return nominal, true, paper.TABLE1_PLANE, paper.EKF_PRESETS["simulation"]
        nominal, true = paper.table6_layouts()
        return nominal, true, paper.TABLE5_PLANE, paper.EKF_PRESETS["experiment"]


@dataclass
class Trial:
    """Results of one seeded trial.

    Attributes
    ----------
    plane_true, plane_fit : (4,) float, (A, B, C, D) with unit normal, the paper's sign
    deviation_deg : dict method -> (n_workpiece,) float, deg
    zero_error_mm : dict method -> (n,) float, mm, |estimated - true zero point|
    direction_error_deg : dict method -> (n,) float, deg, angle estimated/true beam
    n_converged : (n,) int, the paper's EKF (-1: rule never met)
    ekf_history : list of (k, 6) float, the paper's EKF raw estimates per sensor
    residual_rms_mm : dict method -> (n,) float, mm
    """

    plane_true: np.ndarray
    plane_fit: np.ndarray
    deviation_deg: dict
    zero_error_mm: dict
    direction_error_deg: dict
    n_converged: np.ndarray
    ekf_history: list
    residual_rms_mm: dict


def _paper_sign(coeffs, like):
    return coeffs if np.dot(coeffs[:3], like[:3]) >= 0 else -coeffs


def run_trial(cfg: ReproduceConfig, rng: np.random.Generator) -> Trial:
    """One trial of the protocol (module docstring) with its own random stream."""
    nominal, true, table_plane, preset = cfg.tables()
    truth = Plane(table_plane[:3], table_plane[3])
    # step 1: the datum measured by the tracker and fitted
    pts = datum_points(rng, truth.normal, truth.offset, cfg.n_datum_points, cfg.datum_noise_mm, cfg.datum_size_mm)
    fitted, _, _ = fit_plane_tls(pts)
    # steps 2-6: calibration poses; readings from the truth, planes from the fit
    poses = random_poses(rng, nominal, truth.normal, truth.offset, cfg.n_poses, cfg.poses)
    d = simulate_readings(rng, true, *poses.plane_in_tcs(truth.normal, truth.offset), cfg.noise_mm)
    obs = Observations(*poses.plane_in_tcs(fitted.normal, fitted.offset), d)
    # step 7: identification
    sigma = max(cfg.noise_mm, 1e-6)
    fits = {
        "method1": calibrate(nominal, obs, "method1"),
        "ekf_paper": calibrate(nominal, obs, "ekf_paper", Q=preset["Q"], R=preset["R"], delta=preset["delta"]),
        "ekf": calibrate(nominal, obs, "ekf", sigma_mm=sigma),
        "iekf": calibrate(nominal, obs, "iekf", sigma_mm=sigma),
        "lsq": calibrate(nominal, obs, "lsq"),
    }
    layouts = {"before": nominal, **{k: v.layout for k, v in fits.items()}, "true": true}
    # steps 8-10: a workpiece plane of random orientation, 20 poses
    wn = rng.normal(size=3)
    work = Plane(wn, -rng.uniform(100.0, 1000.0))
    wposes = random_poses(rng, nominal, work.normal, work.offset, cfg.n_workpiece, cfg.poses)
    w_normal, w_offset = wposes.plane_in_tcs(work.normal, work.offset)
    wd = simulate_readings(rng, true, w_normal, w_offset, cfg.noise_mm)
    deviation = {}
    for name in METHOD_ORDER:
        lay = layouts[name]
        n_meas = micro_plane_normal(lay.zero, lay.direction, wd)
        deviation[name] = np.rad2deg(angle_between(n_meas, w_normal))
    zero_err = {k: np.linalg.norm(layouts[k].zero - true.zero, axis=1) for k in METHOD_ORDER}
    dir_err = {k: np.rad2deg(angle_between(layouts[k].direction, true.direction, oriented=True)) for k in METHOD_ORDER}
    return Trial(
        plane_true=_paper_sign(truth.coefficients, table_plane),
        plane_fit=_paper_sign(fitted.coefficients, table_plane),
        deviation_deg=deviation,
        zero_error_mm=zero_err,
        direction_error_deg=dir_err,
        n_converged=fits["ekf_paper"].n_converged,
        ekf_history=fits["ekf_paper"].history,
        residual_rms_mm={k: v.residual_rms for k, v in fits.items()},
    )


def run_trials(cfg: ReproduceConfig, seed: int, trials: int, progress=None) -> list:
    """``trials`` independent trials from ``numpy.random.default_rng(seed)``'s spawned streams.

    ``progress(done, total, what)``, if given, is called before each trial and at the end
    (:mod:`metrology.core.progress`).
    """
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    streams = np.random.default_rng(seed).spawn(trials)
    out = []
    for k, rng in enumerate(streams):
        notify(progress, k, trials, f"trial {k + 1} of {trials}")
        out.append(run_trial(cfg, rng))
    notify(progress, trials, trials, "done")
    return out


def summarize(cfg: ReproduceConfig, trials: list, seed: int) -> dict:
    """Tables 1, 3 and 4 analogues (per trial statistics, then mean and spread over trials)."""
    nominal, true, table_plane, preset = cfg.tables()
    t0 = trials[0]
    table4 = {}
    for m in METHOD_ORDER:
        per = [describe(t.deviation_deg[m]) for t in trials]
        row = {}
        for key in ("max_deg", "mean_deg", "std_deg"):
            vals = np.array([p[key] for p in per])
            row[key] = float(vals.mean())
            row[key.replace("_deg", "_spread_deg")] = float(vals.std(ddof=1)) if len(vals) > 1 else 0.0
        row["zero_error_mm"] = float(np.mean([t.zero_error_mm[m].max() for t in trials]))
        row["direction_error_deg"] = float(np.mean([t.direction_error_deg[m].max() for t in trials]))
        table4[m] = row
    conv = np.array([t.n_converged for t in trials])
    paper_t4 = paper.TABLE4 if cfg.layout == "simulation" else paper.TABLE8
    return {
        "layout": cfg.layout,
        "seed": seed,
        "trials": len(trials),
        "config": {
            "n_datum_points": cfg.n_datum_points, "datum_noise_mm": cfg.datum_noise_mm,
            "datum_size_mm": cfg.datum_size_mm, "n_poses": cfg.n_poses, "noise_mm": cfg.noise_mm,
            "n_workpiece": cfg.n_workpiece, "standoff_mm": list(cfg.poses.standoff_mm),
            "tilt_max_deg": float(np.rad2deg(cfg.poses.tilt_max)), "spread_mm": cfg.poses.spread_mm,
            "ekf_paper": preset,
        },
        "table1": {"theoretical": t0.plane_true.tolist(), "fitted_trial1": t0.plane_fit.tolist(),
                   "paper_fitted": paper.TABLE1_FITTED.tolist() if cfg.layout == "simulation" else None},
        "table3": {
            "sensors": list(nominal.names),
            "n_converged_trial1": conv[0].tolist(),
            "never_converged_fraction": (conv < 0).mean(axis=0).tolist(),
            "median_when_converged": [float(np.median(c[c > 0])) if np.any(c > 0) else None for c in conv.T],
            "paper": list(paper.TABLE3_CONVERGENCE if cfg.layout == "simulation" else paper.TABLE7_CONVERGENCE),
        },
        "table4": table4,
        "paper_table4": {k: dict(zip(("max_deg", "mean_deg", "std_deg"), v)) for k, v in paper_t4.items()},
    }
