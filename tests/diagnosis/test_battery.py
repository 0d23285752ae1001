"""The noise-model battery's whiteness test is calibrated at the poses a calibration has."""

import numpy as np
import pytest

from metrology.diagnosis.stats import ljung_box, noise_tests


def test_permutation_ljung_box_is_uniform_on_white_noise():
    # 400 series of 56 values: the share with p <= 0.05 is binomial(400, 0.05) if calibrated
    rng = np.random.default_rng(5)
    p = np.array([ljung_box(rng.normal(size=56), 10, rng, n_perm=199) for _ in range(400)])
    assert 8 <= np.sum(p <= 0.05) <= 34  # 20 expected; 99.9 % binomial bounds
    assert 0.4 < np.median(p) < 0.6


def test_chi_square_approximation_is_not_calibrated_in_the_tail():
    # why the battery uses the permutation: the chi-square tail of Q is too light at 40 values
    rng = np.random.default_rng(6)
    q_small = [ljung_box(rng.normal(size=40), 8) for _ in range(3000)]
    assert np.mean(np.array(q_small) < 0.01) > 0.013  # 1 % if calibrated; measured 1.75 % at 4000


def test_permutation_ljung_box_finds_correlated_noise_and_is_reproducible():
    rng = np.random.default_rng(7)
    e = rng.normal(size=80)
    ar = np.empty(80)
    ar[0] = e[0]
    for k in range(1, 80):
        ar[k] = 0.7 * ar[k - 1] + e[k]
    p1 = ljung_box(ar, 10, np.random.default_rng(1), n_perm=999)
    assert p1 == pytest.approx(1 / 1000)  # no random order reaches Q: the smallest p there is
    assert ljung_box(ar, 10, np.random.default_rng(1), n_perm=999) == p1
    assert ljung_box(np.ones(30), 5, rng) == 1.0  # no scatter: nothing to test


def test_noise_tests_pass_the_generator_to_the_whiteness_test():
    rng = np.random.default_rng(8)
    r = rng.normal(scale=0.005, size=(60, 3))
    r[:, 1] = np.convolve(rng.normal(size=64), np.ones(5) / np.sqrt(5), "valid")[:60] * 0.005
    t = noise_tests(r, np.full(3, 0.005), np.full(3, 55), ("A", "B", "C"), rng=np.random.default_rng(0))
    assert t.sensors["B"].p_whiteness < 0.01
    assert t.sensors["A"].p_whiteness > 0.01
    # the permutation p is a multiple of 1/(n_perm + 1)
    assert (t.sensors["A"].p_whiteness * 10000) == pytest.approx(round(t.sensors["A"].p_whiteness * 10000))
