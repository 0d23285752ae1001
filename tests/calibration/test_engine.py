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


def test_held_readings_are_kept_by_layout_start_and_planes(case):
    """The held sensors' readings at ``theta0`` are kept across problems (every candidate on a
    fold starts there): a kept one is the readings of its own start and planes, read-only."""
    from metrology.calibration.engine import clear_held, geometry
    from metrology.core.model import readings

    ds, cov = case
    clear_held()
    th = np.random.default_rng(2).normal(0, 1e-3, (ds.layout.n, 5))
    a = LeastSquares(ds.layout, ds.obs, np.full(4, 0.003), (), sensors=[0], theta0=th)
    b = LeastSquares(ds.layout, ds.obs, np.full(4, 0.003), (Scale((2,), [1e-3], names=ds.layout.names),), theta0=th, cov=cov)
    assert b.d_full0 is a.d_full0  # kept, not recomputed
    np.testing.assert_array_equal(a.d_full0, readings(*geometry(ds.layout, th), ds.obs.normal, ds.obs.offset)[0])
    with pytest.raises(ValueError):
        a.d_full0[0, 0] = 1.0  # no caller can change another's
    th2 = th.copy()
    th2[3, 0] += 0.01
    c = LeastSquares(ds.layout, ds.obs, np.full(4, 0.003), (), sensors=[0], theta0=th2)
    assert not np.array_equal(c.d_full0[:, 3], a.d_full0[:, 3])  # another start: its own readings
    half = ds.obs.select(np.arange(10))
    d = LeastSquares(ds.layout, half, np.full(4, 0.003), (), sensors=[0], theta0=th)
    np.testing.assert_array_equal(d.d_full0, a.d_full0[:10])  # other planes: their own (the same values)
    assert d.d_full0.shape == (10, ds.layout.n)
