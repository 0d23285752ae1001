"""A knocked sensor (the ``shift`` family): its location, its detectable size, and the diagnosis.

End-to-end data come from the independent forward simulator (:mod:`metrology.sim.forward`); the
component's own ``basis`` is used only for the structural checks.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.effects import REGISTRY, Covariates, Shift
from metrology.jobs.diagnose import diagnose_files
from metrology.sim.forward import draw_case, write_case


def _cov(time_h, n=3):
    p = len(time_h)
    return Covariates(np.asarray(time_h, float), np.full(p, np.nan), np.ones((p, n)), np.ones((p, n)),
                      np.zeros((p, n, 2)), np.tile([30.0, 70.0], (n, 1)))


def test_shift_is_a_registry_entry_with_a_step_basis():
    assert REGISTRY["shift"] is Shift
    t = np.array([0.0, 0.1, 0.3, 0.35, 0.5, 0.9])
    c = Shift((1,), [0.04], names=("a", "b", "c"), at_h=0.32)
    B = c.basis(np.zeros((6, 3)), _cov(t))
    np.testing.assert_array_equal(B[:, 1, 0], [0, 0, 0, 1, 1, 1])
    assert not np.any(B[:, [0, 2]])
    # a subset of poses (a fold) keeps the step where it is in time
    np.testing.assert_array_equal(c.basis(np.zeros((3, 3)), _cov(t).select(np.array([0, 3, 5])))[:, 1, 0], [0, 1, 1])
    assert c.describe()["at"]["time_h"] == pytest.approx(0.32)


@pytest.mark.parametrize("seed", range(5))
def test_locate_finds_the_step_in_time_order(seed):
    """Known answer by construction: noise plus a 6-sigma step at a random pose, poses shuffled
    (time order is not row order), one reading blank."""
    rng = np.random.default_rng(seed)
    p, k = 90, int(rng.integers(10, 80))
    t = np.sort(rng.uniform(0, 2.0, p))
    r = rng.normal(0, 0.005, (p, 3))
    r[k:, 2] += 0.03
    r[int(rng.integers(p)), 2] = np.nan
    perm = rng.permutation(p)
    c = Shift((2,), names=("a", "b", "c")).locate(r[perm], _cov(t[perm]), np.full(3, 0.005))
    assert t[k - 1] < c.at_h < t[k]
    assert perm[c.at_pose] == k and perm[c.before_pose] == k - 1
    m = p - 1  # readings of the sensor
    assert c.searched == m - 2 * Shift.min_side(m) + 1


def test_locate_keeps_a_step_off_the_ends():
    """A jump in the last two poses is not a step (it does not persist): the split stays
    ``min_side`` poses from either end."""
    p = 60
    r = np.zeros((p, 1))
    r[-2:, 0] = 1.0
    c = Shift((0,)).locate(r, _cov(np.arange(p)), np.ones(1))
    assert Shift.min_side(p) <= c.at_pose <= p - Shift.min_side(p)


def test_detectable_size_agrees_with_the_family_rule():
    """The closed form of :meth:`Shift.detectable_size` against
    :func:`metrology.diagnosis.detectable.family_detectable` (the same noncentrality computed by
    least squares, one position at a time)."""
    from metrology.diagnosis.detectable import family_detectable

    rng = np.random.default_rng(7)
    p = 70
    t = np.arange(p, dtype=float)
    J = rng.normal(0, 1, (p, 5))
    fin = np.ones(p, bool)
    c = Shift((0,))
    alpha = 0.01 / 40
    det = c.detectable_size(J, _cov(t, 1), fin, 0.004, alpha)
    _, ks = __import__("metrology.core.effects.shift", fromlist=["step_positions"]).step_positions(t, fin, c.min_side(p))
    lo = int(np.ceil(Shift.DETECT_SIDE_FRACTION * p))
    worst = 0.0
    for k in ks[(ks >= lo) & (ks <= p - lo)]:
        h = (t >= k).astype(float)
        worst = max(worst, family_detectable([h], [(h[:, None], 1, p - 6)], J, 0.004, alpha / len(ks)))
    assert det == pytest.approx(worst, rel=1e-6)


def _diagnose(case, tmp_path):
    paths = write_case(case, tmp_path)
    return diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()


def test_a_knocked_sensor_is_named_with_its_pose_and_size(tmp_path):
    case = draw_case(np.random.default_rng([1, 31]), "shift", size=0.04, noise_mm=0.005, n_poses=80, blanks=0)
    (eff,) = case.effects
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "shift" and res["sensors"] == list(eff.sensors)
    (c,) = res["causes"]
    assert c["at"]["first_pose_after"] == eff.shape["at_pose"]
    assert abs(c["size"]["value"] - 0.04) <= 4 * c["size"]["stderr"]
    assert res["detectable"]["shift"]["sensors"][eff.sensors[0]] < 0.04


def test_a_drift_is_not_a_shift(tmp_path):
    """A warm-up (the most step-like drift) is named ``drift``, not a knock."""
    rng = np.random.default_rng([4, 31])  # a time_warmup draw
    case = draw_case(rng, "drift", size=0.08, noise_mm=0.004, n_poses=90, blanks=0)
    res = _diagnose(case, tmp_path)
    assert "shift" not in [c["cause"] for c in res["causes"]]
    assert res["cause"] == "drift"
    assert case.effects[0].shape["shape"] == "time_warmup"
