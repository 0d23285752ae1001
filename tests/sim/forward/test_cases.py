"""Blind cases: what each family does to the readings, pairs, the files and determinism."""

import hashlib

import numpy as np
import pytest

from metrology.io.export import read_export
from metrology.io.layout import load_layout
from metrology.sim.forward import CATALOGUE, FAMILIES, OUT_OF_CATALOGUE, draw_case, draw_pair, write_case

PER_SENSOR_SMOOTH = ["scale", "nonlinearity", "drift", "incidence", "periodic", "crosstalk"]


def _resid(case):
    return case.export.d - case.d_true


def test_families_are_listed_with_size_ranges():
    assert set(CATALOGUE) == {"pose_error", "scale", "nonlinearity", "drift", "incidence", "plane_form", "outliers", "shift"}
    assert set(OUT_OF_CATALOGUE) == {"periodic", "crosstalk"}
    for name, spec in FAMILIES.items():
        assert spec.size_range[0] <= spec.size_range[1] and spec.unit in ("mm", "readings"), name


def test_none_is_noise_only(rng):
    case = draw_case(rng, "none", noise_mm=0.006, n_poses=150, n_sensors=4, blanks=0)
    r = _resid(case)
    assert case.effects == () and case.family == "none"
    assert np.allclose(r.std(axis=0), 0.006, rtol=5 / np.sqrt(2 * 150))
    assert np.allclose(case.export.tcs2tracker_trans, case.true_trans)


@pytest.mark.parametrize("family", PER_SENSOR_SMOOTH)
def test_a_per_sensor_effect_moves_only_its_sensor_by_its_size(family, rng):
    case = draw_case(rng, family, noise_mm=0.003, n_poses=120, size=0.08, blanks=0)
    (eff,) = case.effects
    assert eff.family == family and len(eff.sensors) == 1 and eff.size == 0.08
    j = case.nominal.names.index(eff.sensors[0])
    r = _resid(case)
    others = np.delete(r, j, axis=1)
    assert np.all(np.abs(others) < 6 * 0.003)  # noise only
    assert np.ptp(r[:, j]) > 0.08 * 0.5  # the effect is there on its sensor
    if family in ("scale", "nonlinearity", "drift", "crosstalk"):
        assert np.ptp(r[:, j]) <= 0.08 + 12 * 0.003


def test_shift_moves_one_sensor_by_a_step_that_stays(rng):
    """A knock moves the zero point along the beam: every later reading of that sensor shorter
    by exactly that much, whatever the pose; the other sensors and earlier poses untouched."""
    case = draw_case(rng, "shift", noise_mm=0.003, n_poses=100, size=0.05, blanks=0)
    (eff,) = case.effects
    k, j = eff.shape["at_pose"], case.nominal.names.index(eff.sensors[0])
    assert 10 <= k <= 90 and abs(eff.shape["zero_moved_mm"]) == 0.05
    truth = case.d_true.copy()
    truth[k:, j] -= eff.shape["zero_moved_mm"]
    assert np.all(np.abs(case.export.d - truth) < 6 * 0.003)
    assert eff.shape["time_s"] == case.export.time_s[k]


def test_pose_error_moves_the_reported_pose_not_the_readings(rng):
    case = draw_case(rng, "pose_error", noise_mm=0.003, size=0.05, blanks=0)
    (eff,) = case.effects
    assert np.all(np.abs(_resid(case)) < 6 * 0.003)
    dT = np.linalg.norm(case.export.tcs2tracker_trans - case.true_trans, axis=1)
    assert np.allclose(dT, eff.shape["offset_mm"])
    assert np.hypot(eff.shape["offset_mm"], 50 * eff.shape["angle_rad"]) == pytest.approx(0.05)
    assert eff.sensors == case.nominal.names


def test_plane_form_shapes_the_datum(rng):
    case = draw_case(rng, "plane_form", size=0.3, blanks=0)
    assert case.surface.form_peak_to_valley() == pytest.approx(0.3, rel=1e-9)
    s, t, w = case.surface.plane_coords(case.cloud)
    assert np.std(w - case.surface.height(s, t)) < 0.02


def test_outliers_are_gross(rng):
    case = draw_case(rng, "outliers", size=4, noise_mm=0.004, blanks=0)
    big = np.abs(_resid(case)) > 0.09
    assert big.sum() == 4 == len(case.effects[0].shape["cells"])
    assert set(case.effects[0].sensors) == {case.nominal.names[j] for j in np.nonzero(big)[1]}


def test_blanks_are_empty_cells(rng):
    case = draw_case(rng, "none", blanks=2)
    assert np.isnan(case.export.d).sum() == 2 and len(case.blanks) == 2


def test_pair_carries_two_causes_on_different_sensors(rng):
    case = draw_pair(rng, "drift", "scale", noise_mm=0.003, sizes=(0.06, 0.08), blanks=0)
    a, b = case.effects
    assert (a.family, b.family) == ("drift", "scale") and case.family == "drift+scale"
    assert a.sensors != b.sensors
    with pytest.raises(ValueError, match="pair"):
        draw_pair(rng, "none", "drift")


def test_draws_are_random_within_the_family(rng):
    shapes = {draw_case(np.random.default_rng(s), "nonlinearity", n_poses=40).effects[0].shape["shape"] for s in range(12)}
    assert len(shapes) >= 2
    counts = {draw_case(np.random.default_rng(s), "none", n_poses=40).nominal.n for s in range(8)}
    assert counts == {3, 4}


def _digest(directory):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())}


def test_same_seed_same_bytes_and_files_read_back(tmp_path):
    dirs = []
    for k, seed in enumerate((7, 7, 8)):
        d = tmp_path / f"c{k}"
        d.mkdir()
        write_case(draw_pair(np.random.default_rng(seed), "incidence", "outliers"), d)
        dirs.append(d)
    a, b, c = (_digest(d) for d in dirs)
    assert set(a) == {"export.csv", "layout.toml", "cloud.ply", "truth.json"}
    assert a == b
    assert all(a[k] != c[k] for k in a)
    exp = read_export(dirs[0] / "export.csv")
    case = draw_pair(np.random.default_rng(7), "incidence", "outliers")
    assert np.allclose(exp.d, case.export.d, atol=1e-9, equal_nan=True)
    assert np.allclose(load_layout(dirs[0] / "layout.toml").zero, case.nominal.zero, atol=1e-6)


def test_unknown_family_is_refused(rng):
    with pytest.raises(ValueError, match="family must be one of"):
        draw_case(rng, "gremlins")
