"""Effects outside the catalogue (issue 54's blind set): each kind from its physics, on one sensor, at
1.5-4 times its detectable size, through the same case files as every blind case."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.sim.forward import draw_outside, write_case
from metrology.sim.forward.outside import DETECT_Z, OUTSIDE_KINDS, SIZE_FACTORS, absorbed_basis, detectable


def test_at_least_eight_kinds_each_naming_its_variables():
    assert len(OUTSIDE_KINDS) >= 8
    assert all(v for v in OUTSIDE_KINDS.values())


@pytest.mark.parametrize("kind", sorted(OUTSIDE_KINDS))
def test_a_kind_draws_one_sensor_at_its_size(kind, tmp_path):
    case = draw_outside(np.random.default_rng([54, 7]), kind)
    (eff,) = case.effects
    assert case.family == "outside" and eff.family == "outside" and eff.shape["kind"] == kind
    assert eff.shape["variables"] == list(OUTSIDE_KINDS[kind]) and len(eff.sensors) == 1
    assert SIZE_FACTORS[0] <= eff.shape["factor"] <= SIZE_FACTORS[1]
    assert 30 <= case.export.n_poses <= 150 and case.nominal.n in (3, 4)
    truth = case.truth_dict()
    assert truth["effects"][0]["in_catalogue"] is False
    write_case(case, tmp_path)  # through the public file contract


def test_the_term_is_on_its_sensor_only():
    """Same seed without and with the term: the readings differ on the drawn sensor only, by the
    stated amplitude times the term's shape (the noise is drawn after it, from the same stream)."""
    rng = np.random.default_rng([54, 8])
    case = draw_outside(rng, "fringe", factor=3.0, n_sensors=4, n_poses=80, noise_mm=0.005, blanks=0)
    eff = case.effects[0]
    i = case.nominal.names.index(eff.sensors[0])
    d_true = case.d_true[:, i]
    term = eff.shape["amplitude"] * np.sin(2 * np.pi * d_true / eff.shape["period_mm"] + eff.shape["phase_rad"])
    r = case.export.d[:, i] - d_true - term
    assert np.std(r) < 2 * case.noise_mm  # what is left is the noise
    assert np.std(case.export.d[:, i] - d_true) > np.std(r)
    assert abs(eff.size - 3.0 * eff.shape["detectable"]) < 1e-12


def test_detectable_size_is_the_unabsorbed_part():
    p = 100
    x = np.linspace(-1, 1, p)
    basis = absorbed_basis(40 + 10 * x, np.zeros((p, 3)))
    # a term the distance absorbs entirely is never detectable; one orthogonal to it is at Z sigma / |g|
    assert detectable(40 + 10 * x, basis, 0.005) == float("inf")
    g = np.sign(np.sin(7 * x))
    det = detectable(g, basis, 0.005)
    r = g - basis @ np.linalg.lstsq(basis, g, rcond=None)[0]
    assert det == pytest.approx(DETECT_Z * 0.005 / np.linalg.norm(r))


def test_heavy_tails_replace_the_noise_of_one_sensor():
    case = draw_outside(np.random.default_rng([54, 9]), "heavy_tails", factor=4.0, n_poses=150, noise_mm=0.005)
    eff = case.effects[0]
    i = case.nominal.names.index(eff.sensors[0])
    r = case.export.d - case.d_true
    others = [j for j in range(case.nominal.n) if j != i]
    kurt = [float(np.nanmean(r[:, j] ** 4) / np.nanmean(r[:, j] ** 2) ** 2) for j in range(case.nominal.n)]
    assert kurt[i] > max(kurt[j] for j in others)
