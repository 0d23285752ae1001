"""core.stats: the one robust scale the diagnosis, the sanity checks and the drift chart use."""

import math

import numpy as np
import pytest
from scipy import stats

from metrology.core.stats import MAD_NORMAL, robust_sigma


def test_robust_sigma_is_scipys_normal_mad():
    x = np.random.default_rng(3).normal(2.0, 0.7, 5001)
    assert robust_sigma(x) == pytest.approx(stats.median_abs_deviation(x, scale="normal"), rel=2e-5)
    assert MAD_NORMAL == pytest.approx(1.0 / stats.norm.ppf(0.75), rel=2e-5)


def test_robust_sigma_estimates_sigma_and_ignores_gross_values_and_nans():
    rng = np.random.default_rng(4)
    x = rng.normal(0.0, 3e-3, 20000)
    x[:200] = 5.0  # 1 % gross readings
    x[200:300] = np.nan
    assert robust_sigma(x) == pytest.approx(3e-3, rel=0.03)
    assert np.std(x[np.isfinite(x)]) > 0.1  # the plain scale is ruined by them


def test_robust_sigma_about_a_given_centre():
    x = np.array([1.0, 2.0, 3.0, 10.0])
    assert robust_sigma(x, about=0.0) == pytest.approx(MAD_NORMAL * 2.5)
    assert robust_sigma(x) == pytest.approx(MAD_NORMAL * 1.0)  # median 2.5: |x - c| = 1.5, 0.5, 0.5, 7.5
    assert math.isnan(robust_sigma([np.nan, np.inf]))
