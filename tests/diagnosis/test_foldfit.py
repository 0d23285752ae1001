"""The k folds of a one-sensor fit solved as one problem find each fold's own minimum."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.calibration.engine import LeastSquares
from metrology.core.effects import Drift, Nonlinearity, PoseError
from metrology.diagnosis import covariates_for
from metrology.diagnosis.fit import FitData, FitOptions, fit, fit_any
from metrology.diagnosis.foldfit import FoldBatch
from metrology.diagnosis.heldout import _training_sets
from metrology.sim.synth import HiddenEffect

from .helpers import run


@pytest.fixture(scope="module")
def case():
    ds, _ = run([HiddenEffect("nonlinearity", "L3", 0.01), HiddenEffect("drift", "L2", 0.008)], 23, 40)
    cov = covariates_for(ds, ds.layout)
    base = fit_any(FitData(ds.layout, ds.obs, cov, ds.layout.noise_mm), (), None, "lsq")
    return ds, cov, base.theta


def _problems(ds, cov, th0, comps, k):
    sets = _training_sets(ds.obs, cov, k)
    return sets, [LeastSquares(ds.layout, o, ds.layout.noise_mm, [c.select(tr) for c in comps], None, th0, c_t)
                  for _, tr, o, c_t in sets]


@pytest.mark.parametrize("k", [5, 3])  # 40 poses in 3 folds: training sets of 26 and 27 poses (padded)
@pytest.mark.parametrize("which", ["drift", "nonlinearity", "both"])
def test_the_batch_finds_each_folds_own_minimum(case, which, k):
    ds, cov, th0 = case
    names = ds.layout.names
    comps = {"drift": (Drift((1,), names=names),), "nonlinearity": (Nonlinearity((2,), names=names),),
             "both": (Drift((2,), names=names), Nonlinearity((2,), names=names))}[which]
    sets, problems = _problems(ds, cov, th0, comps, k)
    assert FoldBatch.applies(problems)
    X = FoldBatch(problems).solve()
    for (_, tr, o, c_t), x, p in zip(sets, X, problems):
        own = fit.uncached(FitData(ds.layout, o, c_t, ds.layout.noise_mm), [c.select(tr) for c in comps], theta0=th0,
                           options=FitOptions(solver="gn", covariance=False))
        i = own.sensors[0]
        # the same minimum to the solver's tolerance (the cost to 1e-10 relative; parameters
        # along the weakly determined directions to ~1e-7 mm)
        assert np.sum(p.residual(x) ** 2) == pytest.approx(own.chi2, rel=1e-9)
        np.testing.assert_allclose(x[:5], own.theta[i], rtol=0, atol=1e-6)
        vals = np.concatenate([c.values for c in own.components])
        np.testing.assert_allclose(x[5:], vals, rtol=1e-5, atol=1e-8)
        assert not np.allclose(x[:5], th0[i], rtol=0, atol=1e-5)  # the fold's fit moved from the start


def test_the_batch_is_for_one_sensors_components_only(case):
    ds, cov, th0 = case
    names = ds.layout.names
    assert not FoldBatch.applies(_problems(ds, cov, th0, (PoseError((), n_poses=40), Drift((1,), names=names)), 5)[1])
    assert not FoldBatch.applies(_problems(ds, cov, th0, (Drift((1,), names=names), Drift((2,), names=names)), 5)[1])
