"""The datum cloud: an independent measurement of the datum's form, against the readings'."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.calibration.dataset import Dataset, check
from metrology.core.effects import PlaneForm, PoseError
from metrology.core.plane import plane_basis
from metrology.diagnosis import FitData, covariates_for, diagnose, fit_any
from metrology.sim.synth import HiddenEffect, synth_cloud, synth_run, typical_layouts

from .helpers import FOLDS, K_SIGMA, N_POSES, PLANE

def test_plane_form_from_cloud_recovers_the_form_within_its_stderr():
    rng = np.random.default_rng(8)
    he = HiddenEffect("plane_form", None, 0.02)
    pts = synth_cloud(rng, PLANE, [he])
    centre = -PLANE.offset * PLANE.normal + 5.0 * PLANE.normal  # off the plane: only in-plane position matters
    form, C = PlaneForm.from_cloud(pts, PLANE.normal, PLANE.offset, centre)
    true = np.array([0.0, 0.0, 0.02, 0.006, -0.01])
    z = (form.values - true) / form.stderr
    assert np.all(np.abs(z) < K_SIGMA), z
    np.testing.assert_allclose(np.sqrt(np.diag(C)), form.stderr)
    # the form evaluated where it was measured reproduces the points' heights
    st = (pts - centre) @ plane_basis(PLANE.normal).T
    w = pts @ PLANE.normal + PLANE.offset
    assert np.std(w - form.height(st)) < 1.1 * 0.010
    with pytest.raises(ValueError, match="m >= 7"):
        PlaneForm.from_cloud(pts[:5], PLANE.normal, PLANE.offset, centre)


@pytest.mark.parametrize("cloud_has_form", [True, False])
def test_datum_cloud_cross_checks_the_readings_form(cloud_has_form):
    """Readings hide a datum bow; a cloud of the same surface agrees with the readings' fit, a
    flat cloud (the datum changed since the scan) is reported as disagreeing."""
    nominal, true = typical_layouts()
    he = HiddenEffect("plane_form", None, 0.01)
    rng = np.random.default_rng(21)
    export, _ = synth_run(rng, true, PLANE, N_POSES, [he])
    pts = synth_cloud(rng, PLANE, [he] if cloud_has_form else [])
    d = diagnose(Dataset(check(export, nominal), nominal, PLANE, pts), folds=FOLDS, sim_reps=1)
    assert d.cause == "plane_form"
    df = d.to_dict()["datum_form"]
    ag = df["against_readings"]
    if cloud_has_form:
        assert df["p_quadratic"] < 1e-6 and ag["agree"] and ag["p"] > 0.01
        assert min(df["visible_rms_mm"]) > 0.003  # a 10 um bow shows as more than the noise
        assert "disagrees" not in d.summary
    else:
        assert df["p_quadratic"] > 1e-3 and not ag["agree"]
        assert "disagrees" in d.summary


def test_flat_readings_against_a_bowed_cloud_lower_the_confidence_of_none():
    nominal, true = typical_layouts()
    rng = np.random.default_rng(22)
    export, _ = synth_run(rng, true, PLANE, N_POSES, [])
    pts = synth_cloud(rng, PLANE, [HiddenEffect("plane_form", None, 0.01)])
    d = diagnose(Dataset(check(export, nominal), nominal, PLANE, pts), folds=FOLDS, sim_reps=1)
    assert d.cause == "none" and d.confidence == "low" and "disagrees" in d.summary
    assert not d.datum_form.against_readings.agree
    # typed: the check, its window, its parameters and the agreement are attributes, the JSON made from them
    from metrology.diagnosis.datum import DatumFormCheck, FormAgreement, SpotWindow
    from metrology.diagnosis.results import Param

    df, ag = d.datum_form, d.datum_form.against_readings
    assert isinstance(df, DatumFormCheck) and isinstance(df.window_mm, SpotWindow) and isinstance(ag, FormAgreement)
    assert df.window_mm.s[0] < df.window_mm.s[1] and df.window_mm.t[0] < df.window_mm.t[1]
    assert all(isinstance(v, Param) and v.unit == "mm" and v.stderr > 0 for v in df.params.values())
    assert ag.p < 0.01 and set(ag.z) == set(PlaneForm.key_params) and ag.fitted_with == ("plane_form",)
    out = d.to_dict()["datum_form"]
    assert list(out) == ["points", "points_used", "window", "window_mm", "radius_mm", "params", "p_quadratic",
                         "visible_rms_mm", "visible_over_noise", "against_readings"]
    assert out["window_mm"] == {"s": list(df.window_mm.s), "t": list(df.window_mm.t)}
    assert all(list(v) == ["value", "unit", "stderr"] for v in out["params"].values())
    assert list(out["against_readings"]) == ["readings", "readings_stderr", "z", "chi2", "p", "agree", "fitted_with"]


@pytest.mark.parametrize("with_pose_error, n_seeds", [
    (True, 4),  # the default run: 4 seeds (sd of the mean ~1.2 about 3, against the bound 6)
    pytest.param(True, 10, marks=pytest.mark.slow),
    pytest.param(False, 10, marks=pytest.mark.slow),  # why the form is fitted with the cause: -m slow
])
def test_form_agreement_is_calibrated_under_pose_errors(with_pose_error, n_seeds):
    """Readings with pose errors, a flat datum and a flat cloud: the readings' form fitted with
    the pose error agrees with the cloud's as chi-square(3) says (mean 3; 10 seeds: sd 0.8).
    A form fitted without it has standard errors ~1.8x too small (mean chi-square ~11)."""
    from metrology.diagnosis import datum_form, form_agreement
    from metrology.core.model import direction_from_tangent, readings

    nominal, true = typical_layouts()
    chi2 = []
    for seed in range(n_seeds):
        rng = np.random.default_rng([31, seed])
        export, _ = synth_run(rng, true, PLANE, N_POSES, [HiddenEffect("pose_error", None, 0.02)])
        ds = Dataset(check(export, nominal), nominal, PLANE, synth_cloud(rng, PLANE))
        sigma = nominal.noise_mm
        base = fit_any(FitData(nominal, ds.obs, covariates_for(ds, nominal), sigma), (), None, "lsq")
        zero = nominal.zero + base.theta[:, :3]
        u = direction_from_tangent(nominal.direction, base.theta[:, 3:])
        cov = covariates_for(ds, nominal.with_params(zero, u))
        comps = [PlaneForm((), names=nominal.names)]
        if with_pose_error:
            comps.append(PoseError((), names=nominal.names, n_poses=N_POSES))
        pf = fit_any(FitData(nominal, ds.obs, cov, sigma), comps, base.theta)
        d0 = readings(zero, u, ds.obs.normal, ds.obs.offset)[0]
        chi2.append(form_agreement(datum_form(ds, FitData(ds.layout, ds.obs, cov, sigma), zero, u, d0), pf).chi2)
    if with_pose_error:
        assert np.mean(chi2) < 6.0, chi2
    else:  # the reason the diagnosis fits the form together with the named cause
        assert np.mean(chi2) > 6.0, chi2


def test_a_form_named_as_scanned_adds_its_gain_after_the_fit_labels_in_the_json():
    # check_datum's scan branch: the readings see the scanned form at a gain; its p replaces the Wald one
    from dataclasses import replace

    from metrology.diagnosis.datum import FormAgreement

    q = dict.fromkeys(PlaneForm.key_params, 0.0)
    ag = FormAgreement(q, q, q, 1.2, 0.75, True, ("plane_form@scan",))
    assert list(ag.to_dict()) == ["readings", "readings_stderr", "z", "chi2", "p", "agree", "fitted_with"]
    scan = replace(ag, scan_gain=0.98, scan_gain_stderr=0.02, p=0.32)
    out = scan.to_dict()
    assert list(out)[-3:] == ["fitted_with", "scan_gain", "scan_gain_stderr"] and out["p"] == 0.32
    assert out["fitted_with"] == ["plane_form@scan"] and (scan.scan_gain, scan.agree) == (0.98, True)
