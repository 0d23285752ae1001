"""The datum plane as a nuisance of the calibration (issue 40): estimated with the sensors under the
scan's covariance, its share carried into the calibration's covariance, the layout's and the
certificate's U. Data from the independent forward simulator (hand-probe datum scans)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from metrology.calibration.calibrate import calibrate_dataset
from metrology.calibration.dataset import load_plane
from metrology.calibration.datum_prior import plane_prior
from metrology.calibration.sanity import load_checked
from metrology.core.plane import plane_basis
from metrology.sim.forward import draw_case, write_case


def _hand_case(seed, tmp_path, n_poses=40):
    case = draw_case(np.random.default_rng([41, seed]), "none", scan="hand", n_poses=n_poses)
    (tmp_path / f"c{seed}").mkdir()
    paths = write_case(case, tmp_path / f"c{seed}")
    return case, load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])


def test_the_covariance_grows_by_the_datums_share(tmp_path):
    _, ds = _hand_case(0, tmp_path)
    with_datum = calibrate_dataset(ds)
    exact = calibrate_dataset(replace(ds, plane_cov=None))
    nuis = with_datum.calibration.datum
    assert nuis is not None and exact.calibration.datum is None
    # the conditional covariance is the one the plane-exact calibration reports (same whitening)
    n = ds.layout.n
    cond = np.array([nuis.cov_conditional[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)])
    np.testing.assert_allclose(np.sqrt(np.einsum("nii->ni", cond)), exact.calibration.stderr, rtol=0.02)
    # every variance grows (never shrinks) by the datum's share, and some by more than 1 %
    v_with = np.einsum("nii->ni", with_datum.calibration.cov)
    v_exact = np.einsum("nii->ni", exact.calibration.cov)
    assert np.all(v_with >= v_exact * (1 - 0.02))
    assert np.max(v_with / v_exact) > 1.01
    assert np.max(nuis.share) > 0.01
    # the shared plane correlates the sensors: the layout's covariance is not block diagonal
    C = with_datum.layout.covariance
    assert np.max(np.abs(C[:5, 5:10])) > 0.0
    assert np.all(np.abs(exact.layout.covariance[:5, 5:10]) == 0.0)
    # the verdict says which: the datum's share as information, the exact plane as a note
    names = [c["name"] for c in with_datum.verdict().to_dict()["checks"]]
    assert any(s.startswith("datum: its uncertainty") for s in names)
    assert any(s.startswith("datum: the plane is taken as exact") for s in
               [c["name"] for c in exact.verdict().to_dict()["checks"]])
    share = with_datum.to_dict()["datum"]["share_of_U"]
    assert not share["exact"] and len(share["sensors"]) == n
    s0 = share["sensors"][0]
    assert all(0 < d < t for d, t in zip(s0["U_datum_zero_mm"], s0["U_zero_mm"]))


def test_the_plane_the_readings_place_is_within_its_stated_uncertainty(tmp_path):
    """Coverage, small: the scan's plane and the joint estimate against the true datum, each in
    its own stated sigmas (tilts), over 8 hand scans."""
    z_scan, z_joint = [], []
    for seed in range(8):
        case, ds = _hand_case(seed, tmp_path, n_poses=35)
        rep = calibrate_dataset(ds)
        e = plane_basis(ds.plane.normal)
        n_true = case.surface.normal * np.sign(case.surface.normal @ ds.plane.normal)
        t_scan = e @ (n_true - ds.plane.normal)
        nuis = rep.calibration.datum
        t_joint = e @ (n_true - nuis.normal)
        z_scan.append(t_scan / np.sqrt(np.diag(nuis.prior)[:2]))
        z_joint.append(t_joint / np.sqrt(np.diag(nuis.posterior)[:2]))
    z_scan, z_joint = np.abs(np.ravel(z_scan)), np.abs(np.ravel(z_joint))
    assert np.max(z_scan) < 4.0 and np.max(z_joint) < 4.0, (z_scan, z_joint)
    # the readings inform the tilt: the joint estimate is not worse than the scan's on the whole
    assert np.sqrt(np.mean(z_joint**2)) < 2.0


def test_plane_json_keeps_the_covariance_or_the_plane_is_exact(tmp_path):
    from metrology.datum import fit_plane_robust
    from metrology.sim.forward import draw_surface, sample_hand_scan

    rng = np.random.default_rng(5)
    surf, _ = draw_surface(rng)
    pts, drawn = sample_hand_scan(surf, rng)
    assert 400 <= drawn["n_points"] <= 1500 and 0.04 <= drawn["noise_mm"] <= 0.08 and drawn["n_strays"] >= 4
    fit = fit_plane_robust(pts)
    path = tmp_path / "plane.json"
    path.write_text(json.dumps(fit.to_dict()))
    plane, _, cov = load_plane(path, with_cov=True)
    np.testing.assert_allclose(cov, fit.covariance, rtol=1e-12, atol=1e-300)
    # the tilt's stated sigma is tens of urad for such a scan
    assert 3e-6 < np.sqrt(plane_prior(plane.normal, cov)[0, 0]) < 1e-4
    bare = {k: v for k, v in fit.to_dict().items() if k != "covariance"}
    path.write_text(json.dumps(bare))
    assert load_plane(path, with_cov=True)[2] is None
    path.write_text(json.dumps({**bare, "covariance": [[1.0, 2.0], [3.0, 4.0]]}))
    with pytest.raises(ValueError, match="plane.json: 'covariance' must be"):
        load_plane(path, with_cov=True)


def test_the_datum_share_is_stated_at_the_certificates_coverage_factor():
    from metrology.calibration.calibrate import COVERAGE_K
    from metrology.report.certificate import COVERAGE_K as CERT_K

    assert COVERAGE_K == CERT_K
