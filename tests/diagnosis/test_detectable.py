"""The detectable sizes of ``metro diagnose`` (95 % power of each family's test on the poses)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from metrology.diagnosis.detectable import noncentrality_95


@pytest.mark.parametrize("alpha", [0.01, 3e-4])
def test_noncentrality_of_a_one_parameter_test_is_the_two_z_sum_squared(alpha):
    # F(1, large dof) is a squared z: 95 % power at level alpha needs (z_{1-alpha/2} + z_{0.95})^2
    lam = noncentrality_95(1, 100000, alpha)
    assert lam == pytest.approx((stats.norm.isf(alpha / 2) + stats.norm.isf(0.05)) ** 2, rel=2e-3)
    # more parameters tested at once need a larger noncentrality for the same power
    assert noncentrality_95(3, 200, alpha) > noncentrality_95(1, 200, alpha)


def _design(zero, u, normal, offset, h=1e-6):
    """Readings of one sensor and their derivatives by finite differences: 3 zero-point
    coordinates, 2 beam tilts (about two axes normal to the beam)."""
    from metrology.core.model import readings

    d0 = readings(zero[None], u[None], normal, offset)[0][:, 0]
    cols = []
    for k in range(3):
        z = zero.copy()
        z[k] += h
        cols.append((readings(z[None], u[None], normal, offset)[0][:, 0] - d0) / h)
    a = np.cross(u, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    for axis in (a, np.cross(u, a)):
        w = u + h * axis
        cols.append((readings(zero[None], w[None], normal, offset)[0][:, 0] - d0) / h)
    return d0, np.stack(cols, axis=1)


def test_detectable_gain_error_matches_an_independent_design_matrix(tmp_path):
    # a null data set of the independent simulator; the scale's detectable size recomputed from
    # a finite-difference design (5 geometry columns and d0) at the true layout
    from metrology.jobs.diagnose import diagnose_files
    from metrology.sim.forward import draw_case, write_case

    case = draw_case(np.random.default_rng(17), "none", n_sensors=3, n_poses=60, noise_mm=0.005, blanks=0)
    paths = write_case(case, tmp_path)
    res = diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()
    det = res["detectable"]
    n_cand = len(res["candidates"])
    ex = case.export
    R, t = ex.tcs2tracker_rot, ex.tcs2tracker_trans
    plane_n = np.asarray(case.surface.normal, float)
    plane_o = -float(plane_n @ np.asarray(case.surface.origin, float))
    normal = np.einsum("pji,j->pi", R, plane_n)  # the plane in each TCS
    offset = plane_o + t @ plane_n
    designs = [_design(case.true.zero[i], case.true.direction[i], normal, offset) for i in range(case.nominal.n)]
    for i, name in enumerate(case.nominal.names):
        d0, J = designs[i]
        span = float(np.ptp(ex.d[:, i][np.isfinite(ex.d[:, i])]))
        lam = noncentrality_95(1, len(d0) - 6, 0.01 / n_cand)
        # the gain against the geometry alone, and against crosstalk from the most collinear
        # other sensor (a shift with its distance, which the gain must beat to be named)
        sig_k = []
        for extra in [None] + [designs[j][0] for j in range(case.nominal.n) if j != i]:
            X = np.column_stack([J, d0] + ([] if extra is None else [extra])) / 0.005
            sig_k.append(float(np.sqrt(np.linalg.inv(X.T @ X)[5, 5])))
        assert det["scale"]["sensors"][name] == pytest.approx(np.sqrt(lam) * max(sig_k) * span, rel=0.02)
        assert max(sig_k) > 2 * sig_k[0]  # crosstalk is the harder alternative at these tilts
    # a gross reading: the flagging threshold plus 1.645 sigma, about 5.9 sigma at 180 readings
    assert det["outliers"]["sensors"][case.nominal.names[0]] == pytest.approx(
        0.005 * (stats.norm.isf(0.01 / (2 * 180)) + stats.norm.isf(0.05)), rel=1e-6)
