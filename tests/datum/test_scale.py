"""The robust noise scales (metrology.datum.scale)."""

import numpy as np
import pytest

from metrology.datum import lqs_scale, truncated_normal_std, window_sigmas
from tests.datum.synthetic import plate_cloud


def test_lqs_scale_is_consistent():
    rng = np.random.default_rng(10)
    pts, _, _, _ = plate_cloud(rng, 2000, sigma=0.05, outliers=0.3, amp=10.0)
    sigma, _ = lqs_scale(pts, rng)
    # the best of 500 triples leaves some tilt: the scale is a little high, never low by much
    assert 0.04 < sigma < 0.09


@pytest.mark.parametrize("k", [0.5, 1.0, 2.0, 3.0, 6.0])
def test_truncated_normal_std_matches_scipy(k):
    from scipy.stats import truncnorm

    assert truncated_normal_std(k) == pytest.approx(truncnorm(-k, k).std(), rel=1e-12)


def test_window_sigmas_recovers_the_window_of_truncated_gaussian_residuals():
    """Residuals drawn from N(0, 1) and kept within +-k: their sd gives back k."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=2_000_000)
    for k in (1.5, 2.5, 3.0):
        kept = x[np.abs(x) <= k]
        assert window_sigmas(k, kept.std()) == pytest.approx(k, rel=0.02)
    assert window_sigmas(1.0, 0.0) == 40.0 and window_sigmas(0.0, 1.0) == float("inf")
