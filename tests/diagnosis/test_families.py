"""Causes as families (issue 12) and several causes at once (issue 15).

The data come from the independent forward simulator (:mod:`metrology.sim.forward`), never
from the components the diagnosis fits, except for the structural checks of the components.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.effects import Covariates, PlaneForm, PoseError
from metrology.jobs.diagnose import diagnose_files
from metrology.sim.forward import draw_case, draw_pair, write_case


def _diagnose(case, tmp_path):
    paths = write_case(case, tmp_path)
    return diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()


def test_rigid_pose_error_columns_are_an_offset_and_two_tilts_per_pose():
    p, n = 5, 4
    rng = np.random.default_rng(0)
    inv_nu = 1.0 / rng.uniform(0.9, 1.0, (p, n))
    st = rng.uniform(-80, 80, (p, n, 2))
    cov = Covariates(np.arange(p, dtype=float), np.full(p, np.nan), np.ones((p, n)), inv_nu, st, np.tile([30., 70.], (n, 1)))
    pe = PoseError((), n_poses=p, tilts=True)
    assert pe.n_params == 3 * p and pe.gauge_dof == 6 and pe.label == "pose_error@rigid"
    B = pe.basis(np.zeros((p, n)), cov).reshape(p, n, p, 3)
    for j in range(p):
        np.testing.assert_allclose(B[j, :, j, 0], inv_nu[j])
        np.testing.assert_allclose(B[j, :, j, 1], st[j, :, 0] / pe.RADIUS_MM * inv_nu[j])
        np.testing.assert_allclose(B[j, :, j, 2], st[j, :, 1] / pe.RADIUS_MM * inv_nu[j])
        assert not np.any(np.delete(B[j], j, axis=1))  # a pose's error touches only its own readings
    # a subset of poses keeps each pose's three values together
    v = np.arange(3.0 * p)
    sub = PoseError((), v, n_poses=p, tilts=True).select(np.array([1, 3]))
    np.testing.assert_array_equal(sub.values, [3, 4, 5, 9, 10, 11])
    # three sensors: an offset and two tilts would take every reading of a pose
    cov3 = Covariates(cov.time_h, cov.temp_c, cov.cos_inc[:, :3], inv_nu[:, :3], st[:, :3], cov.range_mm[:3])
    assert [c.label for c in PoseError.candidates_for_setup(("a", "b", "c"), cov3)] == ["pose_error"]
    assert [c.label for c in PoseError.candidates_for_setup(("a", "b", "c", "d"), cov)] == ["pose_error",
                                                                                           "pose_error@rigid"]


def test_scanned_datum_follows_a_form_no_polynomial_has():
    """The smooth surface of a scan follows a non-polynomial form and averages the tracker noise."""
    rng = np.random.default_rng(3)
    s, t = rng.uniform(-400, 400, 3000), rng.uniform(-300, 300, 3000)

    def form(s, t):
        return 0.06 * np.sin(s / 170.0) * np.cos(t / 230.0) + 0.02 * np.cos(s / 90.0)

    w = form(s, t) + rng.normal(0, 0.010, len(s))  # 10 um tracker noise
    pts = np.stack([s, t, w], axis=1)  # plane z = 0, normal +z: (s, t) are the plane's own axes
    height, (lo, hi) = PlaneForm.scan_surface(pts, np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(3))
    from metrology.core.plane import plane_basis

    B = plane_basis(np.array([0.0, 0.0, 1.0]))
    q = rng.uniform([-350, -250], [350, 250], (200, 2))
    xyz = q[:, :1] * B[0] + q[:, 1:] * B[1]
    err = height(q) - form(xyz[:, 0], xyz[:, 1])
    assert np.sqrt(np.mean(err**2)) < 0.003, np.sqrt(np.mean(err**2))  # well below the 10 um point noise
    assert np.isnan(height(np.array([[1e4, 0.0]])))[0]  # no scan there, no height


def _seed_where(family, pred, n_sensors=4, **kw):
    for seed in range(40):
        case = draw_case(np.random.default_rng([seed, 7]), family, n_sensors=n_sensors, **kw)
        if pred(case):
            return case
    raise AssertionError("no such draw in 40 seeds")


def test_orientation_only_pose_error_is_named_on_a_four_sensor_head(tmp_path):
    case = _seed_where("pose_error", lambda c: c.effects[0].shape["split"] == "orientation", size=0.2, n_poses=80,
                       noise_mm=0.003)
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "pose_error", res["summary"]
    assert res["causes"][0]["label"] == "pose_error@rigid"


def test_two_causes_are_both_named_with_sizes(tmp_path):
    rng = np.random.default_rng([21, 3])
    case = draw_pair(rng, "drift", "outliers", n_sensors=4, n_poses=100, sizes=(0.12, 4))
    res = _diagnose(case, tmp_path)
    named = {(c["cause"], tuple(c["sensors"])) for c in res["causes"]}
    drift = next(e for e in case.effects if e.family == "drift")
    assert ("drift", tuple(drift.sensors)) in named, res["summary"]
    assert any(c == "outliers" for c, _ in named), res["summary"]
    assert len(res["causes"]) == 2 and res["cause"] == res["causes"][0]["cause"]
    d = next(c for c in res["causes"] if c["cause"] == "drift")
    assert d["size"]["unit"] == "mm" and d["size"]["stderr"] > 0
    assert abs(d["size"]["value"] - drift.size) < 4 * d["size"]["stderr"] + 0.1 * drift.size
    assert len(res["steps"]) == 3  # base, then one row per cause added


def _curve_beyond_line_mm(case):
    """Peak-to-valley of the true characteristic less its best straight line, over the distances
    the sensor saw: what makes a characteristic more than a gain error."""
    from metrology.sim.forward.characteristic import Characteristic

    sh = dict(case.effects[0].shape)
    curve = Characteristic(sh.pop("shape"), sh.pop("lo_mm"), sh.pop("hi_mm"), sh)
    d = case.d_true[:, list(case.nominal.names).index(case.sensors[0])]
    x = np.linspace(np.nanmin(d), np.nanmax(d), 201)
    e = curve(x)
    r = e - np.polyval(np.polyfit(x, e, 1), x)
    return float(np.ptp(r))


@pytest.mark.slow  # 65 s; the default run names both members blind (test_blind_forward's clear cases)
@pytest.mark.parametrize("shape", ["gain", "curve"])
def test_characteristic_named_scale_or_nonlinearity_by_held_out_error(shape, tmp_path):
    fam = "scale" if shape == "gain" else "nonlinearity"
    pred = (lambda c: True) if fam == "scale" else (lambda c: _curve_beyond_line_mm(c) > 0.06)
    case = _seed_where(fam, pred, size=0.18, n_poses=120, noise_mm=0.004)
    res = _diagnose(case, tmp_path)
    assert res["cause"] == fam and res["sensors"] == list(case.sensors), res["summary"]
