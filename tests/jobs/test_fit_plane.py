"""The fit-plane job (metrology.jobs.fit_plane) on the bundled datum fixture."""

import sys
from pathlib import Path

import numpy as np
import pytest

from metrology.io.data import DATA_DIR
from metrology.core.paper import TABLE5_PLANE
from metrology.core.plane import Plane
from metrology.datum import truncated_normal_std
from metrology.jobs.fit_plane import fit_plane_file
from tests.datum.synthetic import CHI2_2DOF_3SIGMA, normal_chi2

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "fixtures"))
import make_datum_cloud  # noqa: E402


def test_datum_fixture_recovers_its_truth_and_its_form():
    fit = fit_plane_file(str(DATA_DIR / "datum_cloud.ply"))
    n_true, d_true, centre, (eu, ev) = make_datum_cloud.truth()
    truth = Plane(n_true, d_true)
    assert normal_chi2(fit, truth) < CHI2_2DOF_3SIGMA
    assert abs(fit.plane.offset - truth.offset) < 3 * fit.offset_sigma
    assert np.allclose(fit.plane.coefficients, TABLE5_PLANE / np.linalg.norm(TABLE5_PLANE[:3]), atol=1e-3)
    assert 3150 <= fit.n_inliers <= 3200  # the 100 gross outliers out, ~0.3 % of the plate at 3 sigma
    assert fit.noise_sigma == pytest.approx(make_datum_cloud.NOISE_MM * truncated_normal_std(3.0), rel=0.06)
    f = fit.form
    assert f.significant
    M = fit.axes @ np.column_stack([eu, ev])
    a, b = make_datum_cloud.PLATE_U_MM / 2, make_datum_cloud.PLATE_V_MM / 2
    B, T = make_datum_cloud.BOW_MM, make_datum_cloud.TWIST_MM
    H = M @ np.array([[2 * B / a**2, T / (a * b)], [T / (a * b), 2 * B / b**2]]) @ M.T
    got = np.array([[2 * f.coefficients[3], f.coefficients[4]], [f.coefficients[4], 2 * f.coefficients[5]]])
    sd = np.array([[2 * f.stderr[3], f.stderr[4]], [f.stderr[4], 2 * f.stderr[5]]])
    assert np.all(np.abs(got - H) < 3 * sd)
    assert 0.010 < f.pv < 0.025


def test_fixture_script_is_deterministic(tmp_path):
    p1, o1 = make_datum_cloud.make_cloud(np.random.default_rng(make_datum_cloud.SEED))
    make_datum_cloud.write_ply(tmp_path / "c.ply", p1, make_datum_cloud.COMMENTS)
    assert (tmp_path / "c.ply").read_bytes() == Path(str(DATA_DIR / "datum_cloud.ply")).read_bytes()
    assert int(o1.sum()) == 100
