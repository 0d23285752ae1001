"""The one least-squares engine: its Jacobian is the residual's derivative, and the LSQ estimator is it."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.calibration.dataset import Dataset, check
from metrology.calibration.engine import LeastSquares
from metrology.calibration.estimators import lsq
from metrology.core.effects import Drift, Nonlinearity, PoseError, Scale
from metrology.core.paper import TABLE5_PLANE
from metrology.core.plane import Plane
from metrology.diagnosis import covariates_for
from metrology.sim.synth import HiddenEffect, synth_run, typical_layouts

PLANE = Plane(TABLE5_PLANE[:3], TABLE5_PLANE[3])


@pytest.fixture(scope="module")
def case():
    nominal, true = typical_layouts()
    export, _ = synth_run(np.random.default_rng(4), true, PLANE, 30, [HiddenEffect("drift", "L2", 0.01)])
    ds = Dataset(check(export, nominal), nominal, PLANE)
    return ds, covariates_for(ds, nominal)


def _numeric_jacobian(p, x, h=1e-7):
    cols = []
    for j in range(len(x)):
        dx = np.zeros_like(x)
        dx[j] = h
        cols.append((p.residual(x + dx) - p.residual(x - dx)) / (2 * h))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("make", [
    lambda names, p: (),
    lambda names, p: (Drift((1,), [0.003], names=names, variable="time"), Nonlinearity((1,), [0.01, -0.02], names=names)),
    lambda names, p: (Scale((2,), [1e-3], names=names),),
    lambda names, p: (PoseError((), n_poses=p, names=names), Drift((1,), [0.002], names=names)),
])
def test_jacobian_is_the_residuals_derivative(case, make):
    ds, cov = case
    comps = make(ds.layout.names, ds.obs.n_poses)
    p = LeastSquares(ds.layout, ds.obs, np.full(4, 0.003), comps, theta0=None, cov=cov)
    rng = np.random.default_rng(1)
    x = p.x0 + rng.normal(0, 1e-3, p.x0.size)  # away from the start, inside the chart
    J, Jn = p.jacobian(x), _numeric_jacobian(p, x)
    assert J.shape == Jn.shape
    np.testing.assert_allclose(J, Jn, atol=1e-4 * np.max(np.abs(J)))


def test_lsq_estimator_is_the_engine(case):
    ds, _ = case
    cal = lsq(ds.layout, ds.obs)
    for i in range(ds.layout.n):
        p = LeastSquares(ds.layout, ds.obs, np.ones(ds.layout.n), sensors=[i])
        x = p.solve("gn")
        # Gauss-Newton from the same start reaches the estimator's minimum far inside its uncertainty
        assert np.all(np.abs(x - cal.theta[i]) <= 1e-3 * cal.stderr[i])
        assert p.dof(x) == np.isfinite(ds.obs.d[:, i]).sum() - 5


def test_name_clash_and_two_per_pose_components_refused(case):
    ds, cov = case
    names = ds.layout.names
    with pytest.raises(ValueError, match="clash"):
        LeastSquares(ds.layout, ds.obs, np.ones(4), (Scale((1,), names=names), Scale((1,), names=names)), cov=cov)
    p = ds.obs.n_poses
    with pytest.raises(ValueError, match="per-pose"):
        LeastSquares(ds.layout, ds.obs, np.ones(4), (PoseError((), n_poses=p), PoseError((), n_poses=p, tilts=True)),
                     cov=cov)
