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


# issue 32

def _write_xyz(path, pts):
    path.write_text("".join(f"{float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in pts).replace("nan", "NaN"))
    return path


def test_a_plane_needs_redundant_points_counted_after_nan(tmp_path):
    # four points, one NaN: 3 are left, a plane through them would "fit" with residual dof 0
    path = _write_xyz(tmp_path / "four.xyz", [[0, 0, 0], [100, 0, 0.01], [0, 100, -0.01], [np.nan, 5, 5]])
    with pytest.raises(ValueError, match=r"four\.xyz: 3 points of 4 \(1 with NaN dropped\), need at least 6$"):
        fit_plane_file(path, threshold_mm=1e-6, warn=lambda m: None)
    from metrology.datum import fit_plane_robust
    from metrology.datum.robust import MIN_FIT_POINTS, TooFewPoints

    with pytest.raises(TooFewPoints, match=rf"5 points, need at least {MIN_FIT_POINTS} for a plane fit with redundancy"):
        fit_plane_robust(np.random.default_rng(0).normal(size=(5, 3)))


def _cube_surface(rng, side, n):
    p = rng.uniform(0, side, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, 0.0, side)
    return p


def test_no_unit_doubt_on_a_refused_cloud_and_said_once_on_a_fitted_one(tmp_path, rng):
    # a 2 x 2 x 2 cube's faces densely sampled: "looks like metres" by size, but it is no plate
    said = []
    cube = _write_xyz(tmp_path / "cube.xyz", _cube_surface(rng, 2.0, 3000))
    with pytest.raises(ValueError, match="no datum plane"):
        fit_plane_file(cube, warn=said.append)
    assert said == []
    # a 0.4 x 0.3 m plate in metres: fitted, and the unit doubt is said once
    xy = rng.uniform([0, 0], [0.4, 0.3], (3000, 2))
    plate = _write_xyz(tmp_path / "plate.xyz", np.column_stack([xy, rng.normal(0, 2e-5, len(xy))]))
    fit_plane_file(plate, warn=said.append)
    assert len(said) == 1 and "looks like metres; pass --units m" in said[0]


def test_lines_read_past_after_the_last_element_are_said(tmp_path):
    data = Path(__file__).resolve().parents[1] / "data" / "clouds"
    text = (data / "pcl_comment_at_the_end.ply").read_text()
    rows = "".join(f"{x} {y} {0.001 * (x - y)} 1.0\n" for x in range(3) for y in range(3))
    text = text.replace("element vertex 4", "element vertex 13").replace("comment hi", rows.rstrip() + "\ncomment hi")
    path = tmp_path / "c.ply"
    path.write_text(text)
    said = []
    fit = fit_plane_file(path, threshold_mm=0.01, warn=said.append)
    assert fit.read["ignored_lines"] == [22] and fit.n_points == 13
    assert any("line(s) after the last element read past (line 22)" in m for m in said)


def test_a_scene_refusal_names_the_threshold_option_with_a_value_that_fits():
    # PCL test/milk.pcd: a milk carton on a table, 13704 points (in metres, read as mm here)
    milk = Path(__file__).resolve().parents[1] / "data" / "clouds" / "pcl_milk.pcd"
    said = []
    with pytest.raises(ValueError, match=r"no datum plane: .*; --threshold-mm (\S+) fits the densest plane") as info:
        fit_plane_file(milk, warn=said.append)
    assert said == []  # a refused cloud gets no unit doubt
    import re

    t = float(re.search(r"--threshold-mm (\S+) fits", str(info.value)).group(1))
    fit = fit_plane_file(milk, threshold_mm=t, warn=said.append)
    assert fit.n_inliers >= 0.2 * fit.n_points and fit.threshold == t


def test_fit_plane_of_a_binary_ply_imports_neither_open3d_nor_scipy(tmp_path, rng):
    # issue 32: `import open3d` alone took longer than the whole fit of 10^6 points
    import subprocess

    from metrology.io.clouds import write_ply

    xy = rng.uniform(-100, 100, (5000, 2))
    write_ply(tmp_path / "plate.ply", np.column_stack([xy, rng.normal(0, 0.02, len(xy))]))
    code = ("import sys\nfrom cli.main import main\nsys.argv = ['metro', 'fit-plane', sys.argv[1], '--json']\n"
            "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "heavy = sorted(m for m in ('open3d', 'scipy.special', 'scipy.stats', 'scipy.spatial', 'matplotlib', 'trimesh')"
            " if m in sys.modules)\nprint('HEAVY', heavy, file=sys.stderr)\n")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "plate.ply")], capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[2])
    assert '"n_inliers"' in r.stdout, r.stderr
    assert "HEAVY []" in r.stderr, r.stderr
