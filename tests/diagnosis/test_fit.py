"""The extended fit: against the estimators, exact effects, solvers, the profiled pose error."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.calibration.dataset import Dataset, check
from metrology.calibration.estimators import lsq
from metrology.core.effects import Nonlinearity, PoseError
from metrology.core.layout import SensorLayout
from metrology.diagnosis import FitData, FitOptions, covariates_for, fit, fit_any
from metrology.sim.synth import HiddenEffect, synth_run, typical_layouts

from .helpers import K_SIGMA, N_POSES, PLANE, run, small_case

def test_base_fit_equals_estimators_lsq():
    ds, cov = small_case(1, 40)
    f = fit_any(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), (), None, "lsq")
    cal = lsq(ds.layout, ds.obs)
    # Two solvers of one problem agree far inside the estimate's own uncertainty; how far
    # depends on their stopping rules and the wheels' LAPACK, so the bound is 1e-3 sigma.
    assert np.all(np.abs(f.theta - cal.theta) <= 1e-3 * cal.stderr)


@pytest.mark.parametrize("solver", ["lsq", "gn"])
def test_extended_fit_recovers_exact_effect_and_solvers_agree(solver):
    """No noise: the fit returns the hidden values exactly; Gauss-Newton = least_squares."""
    nominal, true = typical_layouts()
    quiet = SensorLayout(true.names, true.zero, true.direction, np.full(4, 1e-12), true.range_mm)
    export, _ = synth_run(np.random.default_rng(2), quiet, PLANE, 40, [HiddenEffect("nonlinearity", "L2", 0.02)])
    ds = Dataset(check(export, nominal), nominal, PLANE)
    cal = fit_any(FitData(nominal, ds.obs, covariates_for(ds, nominal), np.full(4, 0.003)), (), None, "lsq")
    zero = nominal.zero + cal.theta[:, :3]
    from metrology.core.model import direction_from_tangent
    cov = covariates_for(ds, nominal.with_params(zero, direction_from_tangent(nominal.direction, cal.theta[:, 3:])))
    f = fit(FitData(nominal, ds.obs, cov, np.full(4, 0.003)), [Nonlinearity((1,), names=nominal.names)], theta0=cal.theta,
            options=FitOptions(solver=solver))
    np.testing.assert_allclose(f.components[0].values, [0.01, 0.02], atol=2e-4)
    np.testing.assert_allclose(nominal.zero[1] + f.theta[1, :3], true.zero[1], atol=1e-4)
    assert np.nanmax(np.abs(f.residual)) < 1e-4


def test_pose_error_profiled_recovers_sigma():
    ds, truth = run([HiddenEffect("pose_error", None, 0.005)], 11)
    cov = covariates_for(ds, ds.layout)
    base = fit_any(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), (), None, "lsq")
    f = fit(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), [PoseError((), n_poses=N_POSES)], theta0=base.theta,
            options=FitOptions(solver="gn"))
    e, se = f.components[0].values, f.components[0].stderr
    sig = np.sqrt(np.var(e, ddof=1) - np.mean(se**2))
    assert abs(sig - 0.005) < K_SIGMA * 0.005 / np.sqrt(2 * (N_POSES - 1)) + 5e-4
    assert f.chi2 / f.dof < 1.5


# ---------------------------------------------------------------------------------------
# hidden effects, found blind
