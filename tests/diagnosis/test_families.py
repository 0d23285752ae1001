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


def test_scanned_datum_neighbour_degree_is_the_next_polynomial_fit():
    """``height.neighbour()``: the least-squares surface of the next total degree (the one below
    at the top degree), recomputed here with numpy's 2-D Legendre design; the form's size's
    standard error carries the change of its peak-to-valley between the two."""
    from numpy.polynomial import legendre

    rng = np.random.default_rng(4)
    s, t = rng.uniform(-400, 400, 2000), rng.uniform(-300, 300, 2000)
    w = 0.05 * np.sin(s / 150.0) * np.cos(t / 200.0) + rng.normal(0, 0.008, len(s))
    pts = np.stack([s, t, w], axis=1)
    height, (lo, hi) = PlaneForm.scan_surface(pts, np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(3))
    other = height.neighbour()
    deg = height.degree
    assert deg in PlaneForm.SCAN_DEGREES and other.degree in (deg - 1, deg + 1)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)

    def fit(d):
        x = (np.stack([s, t], axis=1) - mid) / half
        V = legendre.legvander2d(x[:, 0], x[:, 1], [d, d])
        V = V[:, [i * (d + 1) + j for i in range(d + 1) for j in range(d + 1) if i + j <= d]]
        return V @ np.linalg.lstsq(V, w, rcond=None)[0]

    st = np.stack([s, t], axis=1)
    np.testing.assert_allclose(height(st), fit(deg), atol=1e-9)
    np.testing.assert_allclose(other(st), fit(other.degree), atol=1e-9)
    assert np.max(np.abs(other(st) - height(st))) > 1e-4  # another surface, not a copy


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
    case = draw_pair(rng, "drift", "outliers", n_sensors=4, n_poses=60, sizes=(0.12, 4))
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


@pytest.mark.slow  # 10 s; the default run names nonlinearity blind (test_blind_forward's clear cases)
def test_characteristic_beyond_a_line_named_nonlinearity_by_held_out_error(tmp_path):
    case = _seed_where("nonlinearity", lambda c: _curve_beyond_line_mm(c) > 0.06, size=0.18, n_poses=120,
                       noise_mm=0.004)
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "nonlinearity" and res["sensors"] == list(case.sensors), res["summary"]


def _gain_over_span_mm(case):
    """Peak-to-valley of a gain error over the distances its sensor saw (the size ``detectable``
    states for ``scale``)."""
    i = list(case.nominal.names).index(case.sensors[0])
    d = case.d_true[:, i]
    return abs(case.effects[0].shape["gain"]) * float(np.ptp(d[np.isfinite(d)]))


@pytest.mark.slow  # 11 s
def test_gain_error_named_scale_only_where_the_tilts_tell_it_from_crosstalk(tmp_path):
    # A gain error on one sensor and a shift with another sensor's distance (crosstalk, outside
    # the catalogue) differ only where the tilts move the sensors' distances apart. The same gain
    # (-0.45 %: 0.18 mm over the 30-70 mm range) on tilts up to 14 deg is below the detectable
    # size the diagnosis states for it: it is named with confidence ambiguous, crosstalk listed as
    # its rival; on tilts up to 30 deg it is above, and named, with its size.
    def run(tilt, where):
        case = draw_case(np.random.default_rng([0, 7]), "scale", n_sensors=4, size=0.18, n_poses=120,
                         noise_mm=0.004, tilt_max_deg=tilt)
        (tmp_path / where).mkdir()
        res = _diagnose(case, tmp_path / where)
        return case, res, res["detectable"]["scale"]["sensors"][case.sensors[0]]

    case, res, det = run(14.0, "narrow")
    assert _gain_over_span_mm(case) < det
    assert res["cause"] == "scale" and res["confidence"] == "ambiguous", res["summary"]
    assert {r["family"] for r in res["causes"][0]["rivals"]} == {"crosstalk"}
    case, res, det = run(30.0, "wide")
    assert _gain_over_span_mm(case) > det
    assert res["cause"] == "scale" and res["sensors"] == list(case.sensors), res["summary"]
    size = res["causes"][0]["size"]
    assert abs(size["value"] - _gain_over_span_mm(case)) < 3 * size["stderr"]


def test_form_size_standard_error_carries_the_degree_choice(tmp_path):
    # the scanned form's peak-to-valley follows the surface's degree: its standard error is the
    # tracker noise's share at the two extremes and the change at the next degree, in quadrature
    from metrology.core.plane import plane_basis
    from metrology.diagnosis.candidates import covariates_for, scan_points
    from metrology.calibration.sanity import load_checked

    case = draw_case(np.random.default_rng([50, 1, 5, 18]), "plane_form")
    paths = write_case(case, tmp_path)
    ds = load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"], "wxyz", "mm", None,
                      lambda *a: None)
    cov = covariates_for(ds, ds.layout)
    centre = np.mean(ds.datum_points, axis=0)
    centre = centre - ds.plane.distance(centre) * ds.plane.normal
    pts = scan_points(ds, centre)
    height, _ = PlaneForm.scan_surface(pts, ds.plane.normal, ds.plane.offset, centre)
    st = (pts - centre) @ plane_basis(ds.plane.normal).T
    A = np.column_stack([np.ones(len(st)), st])

    def beyond(h):
        w = h(st)
        return w - A @ np.linalg.lstsq(A, w, rcond=None)[0]

    b1, b2 = beyond(height), beyond(height.neighbour())
    assert cov.scan_ptp_mm == pytest.approx(np.ptp(b1), rel=1e-9)
    se_noise = np.hypot(*height.stderr(st[[np.argmax(b1), np.argmin(b1)]]))
    by_degree = abs(np.ptp(b2) - np.ptp(b1))
    assert cov.scan_ptp_se_mm == pytest.approx(np.hypot(se_noise, by_degree), rel=1e-9)
    assert by_degree > 0.2 * se_noise  # on this draw the degree's share is not negligible


def test_lagged_drift_is_named_with_the_member_that_leaves_its_sensor_white(tmp_path, adequacy_spy):
    # the blind study's seed-60 drift draw 9: the zero of L2 follows the air through a 223 s lag
    # (7 % of a 53-minute run), 0.12 mm, 7.2 um noise, 62 poses. Linear in temperature and the
    # lagged member predict held-out poses alike, so the held-out comparisons keep the simpler
    # one, which leaves 10 um RMS on L2 (chi-square p = 2e-6): the drift was `unexplained`.
    # ``adequate_member`` takes the lagged member, which leaves L2 consistent with the noise.
    from dataclasses import replace

    from metrology.diagnosis.decide import diagnose
    from metrology.calibration.sanity import load_checked

    case = draw_case(np.random.default_rng([60, 1, 3, 9]), "drift")
    eff = case.effects[0]
    assert eff.shape["shape"] == "temperature_lag" and eff.sensors == ("L2",)
    paths = write_case(case, tmp_path)
    ds = load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"], "wxyz", "mm", None,
                      lambda *a: None)
    res = diagnose(replace(ds, datum_points=None), sim_reps=1).to_dict()
    assert res["cause"] == "drift" and res["sensors"] == ["L2"], res["summary"]
    assert adequacy_spy[0][:4] == ("drift.L2@temp", False, "drift.L2@lag", True)
    assert res["causes"][0]["label"] == "drift.L2@lag"
    size = res["causes"][0]["size"]
    assert abs(size["value"] - eff.size) < 2 * size["stderr"] + 0.05 * eff.size


def test_a_member_taken_for_adequacy_is_kept_when_a_later_cause_is_added(tmp_path, adequacy_spy):
    # the lagged drift above with three gross readings of 0.09-0.12 mm added on L1 and L3: the
    # drift is chosen first (as drift@lag, for adequacy), then the gross readings. Re-choosing
    # the drift's member given them starts from the simplest member (linear in temperature),
    # which again leaves L2 inconsistent; adequate_member given the others keeps the lag
    from dataclasses import replace

    from metrology.diagnosis.decide import diagnose
    from metrology.calibration.sanity import load_checked

    case = draw_case(np.random.default_rng([60, 1, 3, 9]), "drift")
    paths = write_case(case, tmp_path)
    ds = load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"], "wxyz", "mm", None,
                      lambda *a: None)
    d = ds.export.d.copy()
    for k, i, v in ((5, 0, 0.1), (20, 2, -0.12), (41, 0, 0.09)):
        d[k, i] += v
    res = diagnose(replace(ds, export=replace(ds.export, d=d), datum_points=None), sim_reps=1).to_dict()
    assert [c["label"] for c in res["causes"]] == ["drift.L2@lag", "outliers.L1+L3"], res["summary"]
    assert res["confidence"] == "high"
    rechosen = [c for c in adequacy_spy if c[5] == ("outliers.L1+L3",)]
    assert rechosen and rechosen[0][:4] == ("drift.L2@temp", False, "drift.L2@lag", True)
