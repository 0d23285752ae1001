"""Shared by the diagnosis tests: synthetic runs from the simulator (never the fit's own formulas)."""

from __future__ import annotations

import numpy as np

from metrology.calibration.dataset import Dataset, check
from metrology.core.effects import Drift, Incidence, Nonlinearity, Outliers, PlaneForm, PoseError, Scale
from metrology.core.paper import TABLE5_PLANE
from metrology.core.plane import Plane
from metrology.diagnosis import covariates_for
from metrology.sim.synth import SETUP_EFFECTS, HiddenEffect, synth_run, typical_layouts

PLANE = Plane(TABLE5_PLANE[:3], TABLE5_PLANE[3])
N_POSES = 80
FOLDS = 5  # the CLI default

#: detectable ranges measured by benchmarks/study_diagnose.py on the typical pose set
#: (>= 90 % right cause and sensor over 10 seeded trials at both ends)
DETECTABLE = {
    "drift": (0.002, 0.03),  # mm/K
    "nonlinearity": (0.04, 0.3),  # mm (c3)
    "plane_form": (0.004, 0.05),  # mm (b_ss)
    "pose_error": (0.004, 0.03),  # mm (1 sigma per axis)
    "outliers": (0.06, 1.0),  # mm
}
#: sizes with no detectable range on the typical pose set. A gain error is named only where it
#: predicts held-out poses better than a shift with another sensor's distance (crosstalk,
#: outside the catalogue), and these poses' tilts hardly move the sensors' distances apart: the
#: diagnosis states 0.8-1.3 mm over the readings' span as the detectable size of ``scale`` here
#: (the 5 blind draws), far above a 1.6 % gain. The range was (0.004, 0.016) before that check;
#: the blind set still draws it, and asserts that nothing wrong is named.
BELOW_REACH = {
    "scale": (0.004, 0.016),  # gain error (unitless)
}
#: magnitude check: estimate within K_SIGMA of its own standard error (plus model error)
K_SIGMA = 4.0


def run(effects, seed, n_poses=N_POSES):
    nominal, true = typical_layouts()
    export, truth = synth_run(np.random.default_rng(seed), true, PLANE, n_poses, effects)
    return Dataset(check(export, nominal), nominal, PLANE), truth


def small_case(seed=0, n_poses=30):
    ds, _ = run([], seed, n_poses)
    cov = covariates_for(ds, ds.layout)
    return ds, cov


def all_components(ds, cov):
    names = ds.layout.names
    flags = np.zeros(ds.obs.d.shape, bool)
    flags[[2, 5], [1, 3]] = True
    rng = np.random.default_rng(5)
    return [
        Scale((1,), [2e-3], names=names), Incidence((2,), [0.03], names=names),
        Drift((0,), [0.004], names=names, variable="temp"), Drift((3,), [0.01], names=names, variable="time"),
        Nonlinearity((2,), [0.01, -0.02], names=names), PlaneForm((), rng.normal(0, 0.01, 5), names=names),
        PoseError((), rng.normal(0, 0.01, cov.n_poses), names=names, n_poses=cov.n_poses),
        Outliers((1, 3), [0.1, -0.2], names=names, flags=flags),
        # the richer members of each family
        Nonlinearity((1,), [1e-3, 0.01, -0.02], names=names, with_gain=True),
        Nonlinearity((3,), [1e-3, 0.01, -0.02, 0.005, 0.003], names=names, with_gain=True, order=5),
        Nonlinearity((0,), [1e-3, 0.01, -0.02, 0.005, 0.003, -0.01, 0.02], names=names, with_gain=True, order=0,
                     span=(float(np.nanmin(ds.export.d[:, 0])), float(np.nanmax(ds.export.d[:, 0])))),
        Nonlinearity((2,), np.r_[1e-3, rng.normal(0, 0.01, 10)], names=names, with_gain=True, order=0, knots=8,
                     span=(float(np.nanmin(ds.export.d[:, 2])), float(np.nanmax(ds.export.d[:, 2])))),
        Drift((2,), [0.01, -0.004, 0.003], names=names, variable="time", ref=float(np.mean(cov.time_h)), order=3,
              half=0.5 * float(np.ptp(cov.time_h))),
        Drift((1,), [0.004, -0.002, 0.003], names=names, variable="lag", ref=float(np.mean(cov.temp_c))),
        PlaneForm((), rng.normal(0, 0.01, 9), names=names, order=3),
        PoseError((), rng.normal(0, 0.01, 3 * cov.n_poses), names=names, n_poses=cov.n_poses, tilts=True),
    ]


def draw(effect, seed):
    """A hidden effect drawn blind: sensor and log-uniform size within the detectable range."""
    rng = np.random.default_rng([seed, 99, len(effect)])
    lo, hi = DETECTABLE[effect] if effect in DETECTABLE else BELOW_REACH[effect]
    size = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    sensor = None if effect in SETUP_EFFECTS else ["L1", "L2", "L3", "L4"][int(rng.integers(4))]
    return HiddenEffect(effect, sensor, size)


def study_blind():
    """benchmarks/study_blind.py as a module (its catalogue and drawing of cases)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    try:
        import study_blind
    finally:
        sys.path.pop(0)
    return study_blind
