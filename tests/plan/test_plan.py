"""``metrology.plan``: every planned pose feasible (checked with the independent forward
simulator's beams), the plan at least as D-good as random poses, its prefixes good designs,
and the CSV readable by the export reader."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.calibration.dataset import load_plane
from metrology.io.data import DATA_DIR
from metrology.io.layout import load_layout
from metrology.plan import DatumExtent, Limits, feasible, greedy_order, log_det, plan_poses
from metrology.sim.forward import cast_beams, flat_surface

M = DATA_DIR / "measured"


@pytest.fixture(scope="module")
def setup():
    layout = load_layout(M / "nominal.toml")
    plane, points = load_plane(M / "datum.ply")
    extent = DatumExtent.from_points(plane, points)
    limits = Limits(np.deg2rad(10.0), (42.0, 58.0), layout.range_mm)
    return layout, plane, points, extent, limits


@pytest.fixture(scope="module")
def plan20(setup):
    layout, plane, _, extent, limits = setup
    return plan_poses(layout, plane, extent, 20, limits, layout.noise_mm, np.random.default_rng(0), seed=0)


def test_every_planned_pose_is_feasible_by_the_forward_simulators_beams(setup, plan20):
    """Readings, spots and tilts recomputed by casting the nominal beams at a flat datum
    (metrology.sim.forward, not the model's formulas) and the hull by Delaunay, not half-planes."""
    from scipy.spatial import Delaunay

    layout, plane, points, extent, limits = setup
    poses = plan20.planned.poses
    surface = flat_surface(-plane.offset * plane.normal, -plane.normal, (1e4, 1e4))
    hits = cast_beams(surface, layout.zero, layout.direction, poses.rot, poses.trans)
    assert hits.valid.all()
    lo, hi = layout.range_mm[:, 0] + limits.reading_margin_mm, layout.range_mm[:, 1] - limits.reading_margin_mm
    assert np.all((hits.d >= lo) & (hits.d <= hi)), hits.d
    st = (points - extent.origin) @ extent.basis.T
    spots = (hits.spot.reshape(-1, 3) - extent.origin) @ extent.basis.T
    assert np.all(Delaunay(st).find_simplex(spots) >= 0)
    axis = np.array([0.0, 0.0, 1.0])  # this layout's beams point +z
    tilt = np.degrees(np.arccos(np.clip(-(poses.rot @ axis) @ plane.normal, -1, 1)))
    assert tilt.max() <= 10.0 - 0.1 + 1e-9
    assert np.all(feasible(layout, plane, extent, poses, limits))


def test_planned_beats_random_in_the_criterion_and_the_sigmas(plan20):
    p, r = plan20.planned, plan20.random
    assert p.log_det >= r.log_det
    assert plan20.d_efficiency_random < 1.0
    assert p.stderr[:, :3].max() < r.stderr[:, :3].max()
    assert p.stderr[:, 3:].max() < r.stderr[:, 3:].max()
    assert p.normal_sigma_rad <= r.normal_sigma_rad


def test_the_exchange_never_loses_to_greedy_alone(setup, plan20):
    layout, plane, _, extent, limits = setup
    from metrology.plan import draw_candidates, pose_information, prior_information

    cands = draw_candidates(np.random.default_rng(0), layout, plane, extent, 5000, limits)
    pool = np.flatnonzero(feasible(layout, plane, extent, cands, limits))
    X = pose_information(layout, *cands.plane_in_tcs(plane), layout.noise_mm)
    prior = prior_information(layout.n)
    greedy = log_det(X[greedy_order(X, 20, prior, pool)], prior)
    assert plan20.planned.log_det >= greedy - 1e-9


def test_first_k_of_the_plan_are_a_good_k_design(setup, plan20):
    """Each prefix keeps at least 90 % of the D-efficiency of a plan made for k poses, and beats
    the first k random poses; the sigma curve only falls."""
    layout, plane, _, extent, limits = setup
    n = 5 * layout.n
    for k in (8, 12):
        own = plan_poses(layout, plane, extent, k, limits, layout.noise_mm, np.random.default_rng(0),
                         robustness_trials=0)
        prefix = plan20.planned.curve["log_det"][k - 1]
        assert np.exp((prefix - own.planned.log_det) / n) >= 0.9
        assert prefix > plan20.random.curve["log_det"][k - 1]
    ns = plan20.planned.curve["normal_sigma_rad"][4:]
    assert np.all(np.diff(ns) <= 1e-15)


def test_the_plan_stays_feasible_under_robot_error(plan20):
    rb = plan20.planned.robustness
    assert rb["feasible_fraction"] == 1.0 and rb["d_efficiency_min"] > 0.8


def test_same_seed_same_plan(setup, plan20):
    layout, plane, _, extent, limits = setup
    again = plan_poses(layout, plane, extent, 20, limits, layout.noise_mm, np.random.default_rng(0), seed=0)
    assert np.array_equal(again.planned.poses.trans, plan20.planned.poses.trans)


def test_too_few_feasible_candidates_is_a_one_line_error(setup):
    layout, plane, _, extent, limits = setup
    tight = Limits(np.deg2rad(10.0), (42.0, 58.0), layout.range_mm, reading_margin_mm=9.9)
    with pytest.raises(ValueError, match="candidate poses keep every limit"):
        plan_poses(layout, plane, extent, 20, tight, layout.noise_mm, np.random.default_rng(0), n_candidates=200)
    with pytest.raises(ValueError, match="need at least 5"):
        plan_poses(layout, plane, extent, 4, limits, layout.noise_mm, np.random.default_rng(0))


def test_separating_incidence_adds_its_coefficient_and_the_characteristic_and_shrinks_them(setup):
    layout, plane, _, extent, limits = setup
    plan = plan_poses(layout, plane, extent, 12, limits, layout.noise_mm, np.random.default_rng(1), n_candidates=1000,
                      robustness_trials=0, separate=("incidence",))
    p, r = plan.planned, plan.random
    assert p.columns == ("incidence", "scale", "nonlinearity") and p.stderr.shape == (layout.n, 9)
    assert p.log_det >= r.log_det
    assert p.stderr[:, 5].max() < r.stderr[:, 5].max()
    assert set(plan.to_dict()["planned"]["sensors"][0]["stderr"]) >= {"incidence_c_mm", "scale_k", "nonlinearity_c3_mm"}
    assert plan_poses(layout, plane, extent, 12, limits, layout.noise_mm, np.random.default_rng(1), n_candidates=300,
                      robustness_trials=0, separate=("scale",)).planned.columns == ("scale",)
    with pytest.raises(ValueError, match="--separate form"):
        plan_poses(layout, plane, extent, 12, limits, layout.noise_mm, np.random.default_rng(1), separate=("form",))


def test_the_characteristic_columns_make_incidence_separable_from_it(setup):
    """The gain column is ``d0 / sigma`` and the curve's are ``P2, P3`` of the normalised reading;
    a design that has them predicts a smaller standard error of the incidence coefficient
    *given the characteristic* (five chart parameters, ``c``, ``k``, ``c2``, ``c3``) than the
    same search on the incidence column alone: the criterion uses the new columns."""
    from metrology.core.model import readings
    from metrology.plan import draw_candidates
    from metrology.plan.design import covariance, exchange, pose_information, prior_information

    layout, plane, _, extent, limits = setup
    cands = draw_candidates(np.random.default_rng(2), layout, plane, extent, 1500, limits)
    pool = np.flatnonzero(feasible(layout, plane, extent, cands, limits))
    N, D = cands.plane_in_tcs(plane)
    cols = ("incidence", "scale", "nonlinearity")
    X = pose_information(layout, N, D, layout.noise_mm, cols)
    d0 = readings(layout.zero, layout.direction, N, D)[0]
    ok = np.isfinite(d0)
    np.testing.assert_allclose(X[..., 6][ok], (d0 / layout.noise_mm[None, :])[ok])
    lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
    x = (2 * d0 - lo - hi) / (hi - lo)
    np.testing.assert_allclose(X[..., 7][ok], (0.5 * (3 * x**2 - 1) / layout.noise_mm[None, :])[ok])
    assert pose_information(layout, N, D, layout.noise_mm, ("scale",)).shape[-1] == 6

    def se_c(idx):
        return np.sqrt(covariance(X[idx])[:, 5, 5]).max()

    chosen = {}
    for use in (("incidence",), cols):
        Xc = X[..., :5 + {1: 1, 3: 4}[len(use)]]
        prior = prior_information(layout.n, incidence=use)
        chosen[use] = exchange(Xc, greedy_order(Xc, 20, prior, pool), prior, pool)
    assert se_c(chosen[cols]) < se_c(chosen[("incidence",)])


# issue 32: plans that survive the real head

def _heads_within(rng, layout, zero_mm, direction_rad, k):
    """``k`` layouts within the tolerance: every zero coordinate moved by up to ``zero_mm``, every
    beam turned by up to ``direction_rad`` about a random axis (half of them by exactly that)."""
    from scipy.spatial.transform import Rotation

    for j in range(k):
        z = layout.zero + rng.uniform(-zero_mm, zero_mm, layout.zero.shape)
        axis = rng.normal(size=(layout.n, 3))
        ang = np.full(layout.n, direction_rad) if j % 2 else rng.uniform(0, direction_rad, layout.n)
        R = Rotation.from_rotvec(axis / np.linalg.norm(axis, axis=1)[:, None] * ang[:, None]).as_matrix()
        yield z, np.einsum("nij,nj->ni", R, layout.direction)


def test_reading_bounds_hold_the_readings_of_heads_within_the_tolerance(setup):
    """Readings and spots cast by the forward simulator on 400 heads within 1.5 mm / 3 deg lie
    inside the bounds (metrology.plan.candidates.reading_bounds) at 300 random poses."""
    from metrology.plan.candidates import draw_candidates, pose_readings, reading_bounds

    layout, plane, _, extent, limits = setup
    rng = np.random.default_rng(5)
    poses = draw_candidates(rng, layout, plane, extent, 300, limits)
    tz, tt = 1.5, np.deg2rad(3.0)
    d_lo, d_hi, shift = reading_bounds(layout, plane, poses, tz, tt)
    d0, s0 = pose_readings(layout, plane, poses)
    assert np.all(d_lo < d0) and np.all(d0 < d_hi)
    surface = flat_surface(-plane.offset * plane.normal, -plane.normal, (1e4, 1e4))
    seen_lo, seen_hi = np.full_like(d0, np.inf), np.full_like(d0, -np.inf)
    for z, u in _heads_within(rng, layout, tz, tt, 400):
        hits = cast_beams(surface, z, u, poses.rot, poses.trans)
        assert hits.valid.all()
        assert np.all(hits.d >= d_lo - 1e-9) and np.all(hits.d <= d_hi + 1e-9)
        assert np.all(np.linalg.norm(hits.spot - s0, axis=-1) <= shift + 1e-9)
        seen_lo, seen_hi = np.minimum(seen_lo, hits.d), np.maximum(seen_hi, hits.d)
    assert np.max(seen_lo - d_lo) < 1.5 and np.max(d_hi - seen_hi) < 1.5  # and not far outside what is seen


def test_a_plan_against_the_layout_tolerance_keeps_every_head_within_it_in_range(setup):
    from dataclasses import replace

    layout, plane, _, extent, limits = setup
    tz, tt = 1.5, np.deg2rad(3.0)
    tol = replace(limits, zero_tol_mm=tz, direction_tol_rad=tt)
    plan = plan_poses(layout, plane, extent, 12, tol, layout.noise_mm, np.random.default_rng(1), n_candidates=2000,
                      robustness_trials=0)
    surface = flat_surface(-plane.offset * plane.normal, -plane.normal, (1e4, 1e4))
    lo, hi = layout.range_mm[:, 0] + tol.reading_margin_mm, layout.range_mm[:, 1] - tol.reading_margin_mm
    poses = plan.planned.poses
    for z, u in _heads_within(np.random.default_rng(2), layout, tz, tt, 200):
        hits = cast_beams(surface, z, u, poses.rot, poses.trans)
        assert np.all((hits.d >= lo) & (hits.d <= hi)), hits.d
    cost = plan.tolerance_cost
    assert cost["feasible_without"] > plan.n_feasible
    assert 0 < cost["margin_mm_max"] < 10
    assert cost["normal_sigma_deg"] >= cost["normal_sigma_deg_without"] * 0.99
    assert plan.to_dict()["tolerance_cost"] == cost
    # the nominal plan of the same candidates lets some head read outside the range
    nominal = plan_poses(layout, plane, extent, 12, limits, layout.noise_mm, np.random.default_rng(1), n_candidates=2000,
                         robustness_trials=0)
    assert nominal.tolerance_cost is None
    out = 0
    for z, u in _heads_within(np.random.default_rng(2), layout, tz, tt, 200):
        d = cast_beams(surface, z, u, nominal.planned.poses.rot, nominal.planned.poses.trans).d
        out += int(np.sum((d < layout.range_mm[:, 0]) | (d > layout.range_mm[:, 1])))
    assert out > 0


def test_the_layout_tolerance_from_the_file_or_the_option(tmp_path):
    from metrology.jobs.plan import layout_tolerance

    text = (M / "nominal.toml").read_text()
    path = tmp_path / "tol.toml"
    path.write_text(text + "\n[tolerance]\nzero_mm = 1.5\ndirection_deg = 3\n")
    assert layout_tolerance(path) == (1.5, 3.0)
    assert layout_tolerance(path, (0.5, 1.0)) == (0.5, 1.0)
    assert layout_tolerance(M / "nominal.toml") == (0.0, 0.0)
    path.write_text(text + "\n[tolerance]\nzero_mm = -1\n")
    with pytest.raises(ValueError, match=r"tol\.toml: \[tolerance\]: zero_mm -1, expected a number >= 0"):
        layout_tolerance(path)
    path.write_text(text + "\n[tolerance]\nzero = 1\n")
    with pytest.raises(ValueError, match=r"expected a table of zero_mm and direction_deg"):
        layout_tolerance(path)


def test_cli_layout_tolerance_option():
    import json

    from typer.testing import CliRunner

    from cli.main import app

    args = ["plan", "--layout", str(M / "nominal.toml"), "--plane", str(M / "datum.ply"), "--poses", "6",
            "--candidates", "800"]
    r = CliRunner().invoke(app, [*args, "--layout-tolerance", "1.5,3", "--json"])
    assert r.exit_code == 0, r.output
    cost = json.loads(r.stdout)["tolerance_cost"]
    assert (cost["zero_mm"], cost["direction_deg"]) == pytest.approx((1.5, 3.0)) and cost["margin_mm_max"] > 0
    r = CliRunner().invoke(app, [*args, "--layout-tolerance", "1.5"])
    assert r.exit_code == 2 and "expected two numbers ZERO_MM,DIRECTION_DEG" in r.stderr
    r = CliRunner().invoke(app, [*args, "--layout-tolerance", "1.5,-3"])
    assert r.exit_code == 2 and "direction_deg -3.0, expected a number >= 0" in r.stderr
