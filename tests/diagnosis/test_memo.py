"""No fit computed twice: kept results are the results, keyed by everything they depend on."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.effects import Drift, Nonlinearity, PoseError
from metrology.diagnosis import covariates_for
from metrology.calibration.kept import content_key
from metrology.diagnosis.fit import FitData, FitOptions, clear_all, fit, fit_any
from metrology.diagnosis.heldout import _solve_per_pose, kfold
from metrology.sim.synth import HiddenEffect

from .helpers import FOLDS, run


@pytest.fixture(scope="module")
def case():
    ds, _ = run([HiddenEffect("drift", "L2", 0.01), HiddenEffect("pose_error", None, 0.004)], 21, 40)
    cov = covariates_for(ds, ds.layout)
    base = fit_any(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), (), None, "lsq")
    return ds, cov, base.theta


def test_content_key_sees_values_dtype_shape_and_fields():
    a = np.arange(6.0).reshape(2, 3)
    assert content_key(a) == content_key(a.copy())
    b = a.copy()
    b[1, 2] += 1e-15 * b[1, 2]  # one ulp-sized change
    assert content_key(a) != content_key(b)
    assert content_key(a) != content_key(a.astype(np.float32))
    assert content_key(a) != content_key(a.reshape(3, 2))
    names = ("L1", "L2", "L3", "L4")
    assert content_key(Drift((1,), names=names)) == content_key(Drift((1,), names=names))
    assert content_key(Drift((1,), names=names)) != content_key(Drift((2,), names=names))
    assert content_key(Drift((1,), names=names)) != content_key(Drift((1,), names=names, variable="time"))
    assert content_key(Drift((1,), [0.0], names=names)) != content_key(Drift((1,), [1e-300], names=names))


def test_a_kept_fit_is_the_fit_and_read_only(case):
    ds, cov, th0 = case
    comps = (Nonlinearity((2,), names=ds.layout.names),)
    clear_all()
    f1 = fit(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, theta0=th0, options=FitOptions(solver="gn"))
    f2 = fit(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, theta0=th0, options=FitOptions(solver="gn"))
    assert f2 is f1  # kept
    fresh = fit.uncached(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, theta0=th0, options=FitOptions(solver="gn"))
    np.testing.assert_array_equal(fresh.theta, f1.theta)
    np.testing.assert_array_equal(fresh.residual, f1.residual)
    np.testing.assert_array_equal(fresh.components[0].values, f1.components[0].values)
    with pytest.raises(ValueError):
        f1.residual[0, 0] = 0.0  # a shared result cannot be changed by one of its readers
    # another input, another fit
    f3 = fit(FitData(ds.layout, ds.obs, cov, 2 * ds.layout.noise_mm), comps, theta0=th0, options=FitOptions(solver="gn"))
    assert f3 is not f1 and f3.chi2 != f1.chi2


@pytest.mark.parametrize("comps", [(Drift((1,), variable="time"),), (PoseError((), n_poses=40), Drift((1,)))])
def test_a_fit_without_covariance_has_the_same_minimum(case, comps):
    """The k-fold's fits skip the covariance: the same values, residuals, chi-square and dof."""
    ds, cov, th0 = case
    a = fit.uncached(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, theta0=th0, options=FitOptions(solver="gn"))
    b = fit.uncached(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, theta0=th0,
                       options=FitOptions(solver="gn", covariance=False))
    np.testing.assert_array_equal(a.theta, b.theta)
    np.testing.assert_array_equal(a.residual, b.residual)
    assert (a.chi2, a.dof) == (b.chi2, b.dof)
    for ca, cb in zip(a.components, b.components):
        np.testing.assert_array_equal(ca.values, cb.values)
    assert np.all(a.theta_stderr[list(a.sensors)] > 0)


def test_kfold_kept_or_not_the_same(case):
    ds, cov, th0 = case
    comps = (PoseError((), n_poses=40), Drift((1,), names=ds.layout.names))
    clear_all()
    h1 = kfold(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, FOLDS, th0)
    clear_all()
    h2 = kfold.uncached(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), comps, FOLDS, th0)
    np.testing.assert_array_equal(h1.residual, h2.residual)
    np.testing.assert_array_equal(h1.normal_dev, h2.normal_dev)
    assert np.isfinite(h1.residual).sum() > 0.9 * h1.residual.size


@pytest.mark.parametrize("m, prior", [(1, False), (3, True)])
def test_stacked_leave_one_out_solves_equal_one_at_a_time(m, prior):
    """The held-out per-pose values, every sensor left out in one stacked call, are those of
    leaving each out in turn."""
    rng = np.random.default_rng(3)
    h, n = 7, 4
    w, r = rng.normal(size=(h, n, m)), rng.normal(size=(h, n))
    P = np.diag(rng.uniform(1, 2, m)) if prior else None
    wi = np.repeat(w[None], n, axis=0)
    wi[np.arange(n), :, np.arange(n), :] = 0.0
    stacked = _solve_per_pose(wi, np.broadcast_to(r, wi.shape[:3]), P)
    for i in range(n):
        one = w.copy()
        one[:, i, :] = 0.0
        np.testing.assert_allclose(stacked[i], _solve_per_pose(one, r, P), rtol=1e-12, atol=1e-12)
