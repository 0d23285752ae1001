"""The datum's quadratic form and its F-test (metrology.datum.form)."""

import json
import math

import numpy as np
import pytest

from metrology.io.data import DATA_DIR
from metrology.datum import DatumForm, fit_plane_robust
from metrology.jobs.fit_plane import fit_plane_file
from tests.datum.synthetic import plate_cloud


def test_quadratic_form_is_recovered_in_its_own_axes():
    cuu, cuv, cvv = 2.0e-7, -1.2e-7, 3.5e-7  # 1/mm
    rng = np.random.default_rng(11)
    pts, truth, R, t = plate_cloud(rng, 40000, sigma=0.002, outliers=0.02, form=lambda u, v: cuu * u * u + cuv * u * v + cvv * v * v)
    # the form (P-V ~0.02 mm) dwarfs the noise here: a band of 3 noise sigma about the
    # plane would clip its extremes, so the threshold is set wide enough (see the docs)
    fit = fit_plane_robust(pts, seed=3, threshold_mm=0.05)
    f = fit.form
    assert f.significant and f.p_value < 1e-100
    # the truth's Hessian, in the fit's (u, v) axes
    M = fit.axes @ R[:, :2]  # fit axes in the plate's (u, v) basis
    sign = np.sign(fit.plane.normal @ R[:, 2])  # residuals are signed along the fit's normal
    H = sign * M @ np.array([[2 * cuu, cuv], [cuv, 2 * cvv]]) @ M.T
    got = np.array([[2 * f.coefficients[3], f.coefficients[4]], [f.coefficients[4], 2 * f.coefficients[5]]])
    sd = np.array([[2 * f.stderr[3], f.stderr[4]], [f.stderr[4], 2 * f.stderr[5]]])
    assert np.all(np.abs(got - H) < 4 * sd + 1e-12)
    # the fitted surface reproduces the form: what is left about it is the noise
    inl = pts[fit.inliers(pts)]
    uv = (inl - fit.centroid) @ fit.axes.T
    left = fit.residuals(inl) - f.evaluate(uv[:, 0], uv[:, 1])
    assert np.std(left) == pytest.approx(0.002, rel=0.05)
    assert fit.rms > 1.5 * 0.002  # the plane alone leaves the form in its residuals
    assert f.pv == pytest.approx(np.ptp(f.evaluate(uv[:, 0], uv[:, 1])), rel=0.05)


def test_flat_plate_form_false_alarm_rate():
    """A flat plate: the F-test at alpha = 0.01 fires in about 1 % of seeded trials."""
    alarms = 0
    for seed in range(200):
        rng = np.random.default_rng(1000 + seed)
        pts, _, _, _ = plate_cloud(rng, 300, outliers=0.0)
        alarms += fit_plane_robust(pts, seed=seed).form.significant
    assert alarms <= 8  # binomial(200, 0.01): P(>= 9) < 1e-3


def test_form_is_none_with_few_inliers():
    pts = np.array([[0, 0, 0], [100, 0, 0.01], [0, 100, -0.01], [100, 100, 0.0], [50, 50, 0.02], [30, 70, -0.01]], float)
    fit = fit_plane_robust(pts, threshold_mm=1.0)
    assert fit.form is None and fit.n_inliers == 6 and fit.to_dict()["form"] is None


def test_plane_form_dict_round_trips_to_json():
    fit = fit_plane_file(str(DATA_DIR / "datum_cloud.ply"))
    d = json.loads(json.dumps(fit.to_dict()))
    assert isinstance(fit.form, DatumForm)
    assert d["form"]["coefficients"]["cuu_per_mm"] == fit.form.coefficients[3]
    assert d["normal_sigma_deg"] == pytest.approx(math.degrees(fit.normal_sigma))


def _rel_fdtrc():
    import scipy

    major, minor = (int(x) for x in scipy.__version__.split(".")[:2])
    return 1e-9 if (major, minor) >= (1, 12) else 2e-7


REL_FDTRC = _rel_fdtrc()


@pytest.mark.parametrize("d1", [1, 3, 7])
def test_f_survival_function_matches_scipy(d1):
    from scipy.special import fdtrc

    from metrology.datum.form import f_sf

    for d2 in [1, 2, 5, 30, 997, 10**5, 10**7]:
        for f in [0.0, 1e-6, 0.01, 0.3, 1.0, 2.5, 10.0, 100.0, 1e4, 1e8]:
            want = float(fdtrc(d1, d2, f))
            got = f_sf(d1, d2, f)
            # scipy's own fdtrc is the reference: Boost's (newer scipy) agrees to 1e-9; the Cephes one of
            # the lowest scipy allowed (1.11) is itself off by up to 1.2e-7 at d2 = 1e7
            assert got == pytest.approx(want, rel=REL_FDTRC, abs=1e-300), (d1, d2, f)
