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


def test_a_fold_locates_the_step_without_its_held_out_poses():
    """Known answer by construction: the only excursion is in the poses of one fold (every fifth
    pose from 40 on). Located on every pose, the step sits at 40; restricted to the other folds'
    poses (what the k-fold fits), it is located in their residuals, which carry no step there,
    and its place is not the held-out fold's excursion."""
    p = 100
    r = np.zeros((p, 1))
    r[40::5, 0] = 1.0  # fold 0 of 5 (poses 0, 5, 10, ...), from pose 40 on
    t = np.arange(p, dtype=float)
    c = Shift((0,)).locate(r, _cov(t, 1), np.ones(1))
    assert c.at_h == pytest.approx(39.5)
    train = np.setdiff1d(np.arange(p), np.arange(0, p, 5))
    c_train = c.select(train)
    assert c_train.at_h != pytest.approx(39.5)
    # and the restricted step is the one located in the training residuals alone
    alone = Shift((0,)).locate(r[train], _cov(t[train], 1), np.ones(1))
    assert (c_train.at_h, c_train.at_pose, c_train.searched) == (alone.at_h, alone.at_pose, alone.searched)
    assert Shift((0,), at_h=39.5).select(train).at_h == 39.5  # a step placed by hand stays put


def test_a_pose_inside_the_located_gap_is_predicted_by_its_chance_of_being_after():
    """The data place a knock between the two poses that bracket it. On the poses it was located
    among the term is the plain step; a pose held out from between them (times 19 | 21 bracket
    the training poses' step, the held-out pose is at 20.5) gets the step times its chance of
    coming after a knock uniform in that interval."""
    t = np.r_[np.arange(20.0), 20.5, np.arange(21.0, 40.0)]
    r = np.zeros((40, 1))
    r[20:, 0] = 1.0
    cov = _cov(t, 1)
    c = Shift((0,)).locate(r, cov, np.ones(1))
    np.testing.assert_array_equal(c.basis(np.zeros((40, 1)), cov)[:, 0, 0], (np.arange(40) >= 20).astype(float))
    train = np.setdiff1d(np.arange(40), [20])
    f = c.select(train)
    assert f.gap_h == (19.0, 21.0)
    B = f.basis(np.zeros((40, 1)), cov)[:, 0, 0]
    assert B[20] == pytest.approx(0.75)
    np.testing.assert_array_equal(np.delete(B, 20), np.delete((np.arange(40) >= 20).astype(float), 20))


def test_a_located_step_on_nulls_costs_held_out_prediction():
    """On forward-simulated runs with no step, a step located in the residuals and judged by the
    k-fold held-out gain must on average predict the held-out poses worse than the base model
    (it fits noise). Located on every pose, the place is chosen knowing the held-out readings
    and the held-out test favours it (mean z of the one-sided test about +0.1 to +0.6 on such
    draws, against -1.1 to -1.4 re-located per fold)."""
    import tempfile
    from dataclasses import replace

    from scipy import stats

    from metrology.calibration.dataset import load_dataset
    from metrology.diagnosis.candidates import covariates_for
    from metrology.diagnosis.fit import FitData, fit_any
    from metrology.diagnosis.heldout import kfold
    from metrology.diagnosis.stats import paired_gain_p

    z = []
    for j in range(4):
        case = draw_case(np.random.default_rng([0, 30, j]), "none", n_poses=60, blanks=0, n_cloud=300)
        with tempfile.TemporaryDirectory() as d:
            paths = write_case(case, d)
            ds = load_dataset(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
        ds = replace(ds, datum_points=None, datum_cloud=None)  # a step needs no datum covariates
        nom, obs, sigma = ds.layout, ds.obs, ds.layout.noise_mm
        cov = covariates_for(ds, nom)
        base = fit_any(FitData(nom, obs, cov, sigma), (), None, "lsq")
        ho0 = kfold(FitData(nom, obs, cov, sigma), (), 5, base.theta)
        for i in range(nom.n):
            c = Shift((i,), names=nom.names).locate(base.residual, cov, sigma)
            ho = kfold(FitData(nom, obs, cov, sigma), (c,), 5, base.theta)
            p = paired_gain_p(ho0.chi2_pose(sigma, [i]) - ho.chi2_pose(sigma, [i]))
            z.append(float(stats.norm.isf(np.clip(p, 1e-12, 1 - 1e-12))))
    assert len(z) >= 12
    assert np.mean(z) < -0.5


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
