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


@pytest.fixture(scope="module")
def null_run(tmp_path_factory):
    """A null data set of the independent simulator (3 sensors, 60 poses, 5 um), its diagnosis,
    and the datum in each pose's TCS (normal (p, 3), offset (p,) mm) at the truth."""
    from metrology.jobs.diagnose import diagnose_files
    from metrology.sim.forward import draw_case, write_case

    case = draw_case(np.random.default_rng(17), "none", n_sensors=3, n_poses=60, noise_mm=0.005, blanks=0)
    paths = write_case(case, tmp_path_factory.mktemp("null"))
    res = diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()
    ex = case.export
    plane_n = np.asarray(case.surface.normal, float)
    plane_o = -float(plane_n @ np.asarray(case.surface.origin, float))
    normal = np.einsum("pji,j->pi", ex.tcs2tracker_rot, plane_n)  # the plane in each TCS
    return case, res, normal, plane_o + ex.tcs2tracker_trans @ plane_n


def _explained(J, s, B, sigma=0.005):
    """What the columns ``B`` explain of the shape ``s`` beyond the geometry ``J``, whitened: the
    noncentrality of a unit size."""
    X0, y = J / sigma, s / sigma
    X1 = np.column_stack([X0, B / sigma])
    r0 = y - X0 @ np.linalg.lstsq(X0, y, rcond=None)[0]
    r1 = y - X1 @ np.linalg.lstsq(X1, y, rcond=None)[0]
    return float(r0 @ r0 - r1 @ r1)


def test_detectable_gain_error_matches_an_independent_design_matrix(null_run):
    # a null data set of the independent simulator; the scale's detectable size recomputed from
    # a finite-difference design (5 geometry columns and d0) at the true layout
    case, res, normal, offset = null_run
    det = res["detectable"]
    n_cand = len(res["candidates"])
    ex = case.export
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


def test_family_detectable_is_the_worst_shape_by_its_best_member():
    # a member detects its own shape at sqrt(lambda_95 / |s|^2) once the base took its part;
    # a shape the base absorbs whole is invisible (inf); the family is its worst shape
    from metrology.diagnosis.detectable import family_detectable

    x = np.linspace(-1.0, 1.0, 50)
    J = np.ones((50, 1))  # the base: a constant
    lin, sq = x.copy(), x**2
    members = [(lin[:, None], 1, 40), (sq[:, None], 1, 40)]
    lam = noncentrality_95(1, 40, 1e-3)
    own = family_detectable([lin], members, J, 0.01, 1e-3)
    assert own == pytest.approx(np.sqrt(lam / np.sum((lin / 0.01) ** 2)))
    sq_c = sq - sq.mean()
    assert family_detectable([sq], members, J, 0.01, 1e-3) == pytest.approx(np.sqrt(lam / np.sum((sq_c / 0.01) ** 2)))
    both = family_detectable([lin, sq], members, J, 0.01, 1e-3)
    assert both == max(own, family_detectable([sq], members, J, 0.01, 1e-3))
    assert family_detectable([np.ones(50)], members, J, 0.01, 1e-3) == np.inf
    # a blank reading is left out of the shape and the designs alike
    gap = lin.copy()
    gap[3] = np.nan
    keep = np.arange(50) != 3
    lin_c = lin[keep] - lin[keep].mean()
    assert family_detectable([gap], members, J, 0.01, 1e-3) == pytest.approx(np.sqrt(lam / np.sum((lin_c / 0.01) ** 2)))


def test_detectable_incidence_is_the_least_favourable_even_shape(null_run):
    # the incidence's detectable size recomputed from a finite-difference design at the true
    # layout: the worst of (a / a_max)^2, ^4, ^6, each by the better of the tan^2 and
    # tan^2 + tan^4 members; on these poses the slowest shape, a^2, is the worst, and its size is
    # well above what the tan^2 member's own shape needs
    case, res, normal, offset = null_run
    det = res["detectable"]["incidence"]["sensors"]
    alpha = 0.01 / len(res["candidates"])
    p = case.export.d.shape[0]
    for i, name in enumerate(case.nominal.names):
        _, J = _design(case.true.zero[i], case.true.direction[i], normal, offset)
        a = np.arccos(np.abs(normal @ case.true.direction[i]))
        t2 = np.tan(a) ** 2
        # (each member is fitted to its own sensor's readings: p - 5 - k residual dof)
        members = [(t2[:, None], p - 6), (np.column_stack([t2, t2**2]), p - 7)]
        by_member = np.array([[np.sqrt(noncentrality_95(B.shape[1], dof, alpha) / _explained(J, (a / a.max()) ** k, B))
                               for B, dof in members] for k in (2, 4, 6)])  # (shape, member)
        sizes = by_member.min(axis=1)
        assert det[name] == pytest.approx(max(sizes), rel=2e-3)
        assert max(sizes) == sizes[0]
        if name != "L1":  # here the tan^2 + tan^4 member is the better one for a^2
            assert by_member[0, 0] > 1.1 * det[name]
        own = np.sqrt(noncentrality_95(1, p - 6, alpha) / _explained(J, t2 / t2.max(), t2[:, None]))
        assert det[name] > 1.2 * own


def test_detectable_nonlinearity_is_the_least_favourable_legendre_shape(null_run):
    # recomputed from a finite-difference design at the true layout: the worst of P2, P3, P4 of
    # the reading over its span (each of peak-to-valley 1 beyond its best line), each by the best
    # of the members gain + P2..P3, gain + P2..P5 and gain + the 4-knot spline (scipy's B-splines
    # less their line over the span)
    from numpy.polynomial import legendre
    from scipy.interpolate import BSpline

    case, res, normal, offset = null_run
    det = res["detectable"]["nonlinearity"]["sensors"]
    alpha = 0.01 / len(res["candidates"])
    ex = case.export
    p = ex.d.shape[0]
    grid = np.linspace(-1.0, 1.0, 401)
    for i, name in enumerate(case.nominal.names):
        d0, J = _design(case.true.zero[i], case.true.direction[i], normal, offset)
        lo, hi = case.nominal.range_mm[i]
        x = (2 * d0 - lo - hi) / (hi - lo)  # over the sensor's range (the members' variable)
        a, b = (2 * np.nanmin(ex.d[:, i]) - lo - hi) / (hi - lo), (2 * np.nanmax(ex.d[:, i]) - lo - hi) / (hi - lo)
        xs = (2 * d0 - d0.min() - d0.max()) / (d0.max() - d0.min())  # over the readings' span (the shapes')
        t = np.concatenate([[a] * 4, np.linspace(a, b, 6)[1:-1], [b] * 4])
        g = np.linspace(a, b, 201)
        G = BSpline.design_matrix(g, t, 3).toarray()
        line = np.linalg.lstsq(np.column_stack([np.ones_like(g), g]), G, rcond=None)[0]
        S = BSpline.design_matrix(np.clip(x, a, b), t, 3).toarray() - line[0] - np.outer(x, line[1])
        members = [(np.column_stack([d0, legendre.legvander(x, 3)[:, 2:]]), 3),
                   (np.column_stack([d0, legendre.legvander(x, 5)[:, 2:]]), 5),
                   (np.column_stack([d0, S[:, 1:-1]]), 7)]
        by = np.empty((3, 3))  # (shape P2..P4, member)
        for r, k in enumerate((2, 3, 4)):
            c = np.zeros(k + 1)
            c[k] = 1.0
            e = legendre.legval(grid, c)
            e = e - np.polyval(np.polyfit(grid, e, 1), grid)
            shape = legendre.legval(xs, c) / np.ptp(e)
            for m, (B, kk) in enumerate(members):
                by[r, m] = np.sqrt(noncentrality_95(kk, p - 5 - kk, alpha) / _explained(J, shape, B))
        assert det[name] == pytest.approx(by.min(axis=1).max(), rel=2e-3)
        # P4 is the richer members' business: the simplest alone would state a size over 1.5 times
        # as large (on these poses the worst shape is then P3)
        assert by[:, 0].max() > 1.5 * det[name]
