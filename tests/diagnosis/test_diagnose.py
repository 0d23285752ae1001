"""metro diagnose: components, the extended fit, hidden effects found blind, null data, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metrology.io.data import DATA_DIR
from metrology.calibration.dataset import Dataset, check
from metrology.diagnosis.candidates import covariates_for
from metrology.diagnosis.decide import diagnose
from metrology.diagnosis.fit import fit_model, fit
from metrology.core.effects import (Covariates, Drift, ExtendedModel, Incidence, Nonlinearity, Outliers, PlaneForm,
                               PoseError, Scale)
from metrology.calibration.estimators import lsq
from metrology.core.layout import SensorLayout
from metrology.core.paper import TABLE5_PLANE
from metrology.core.plane import Plane
from metrology.core.plane import plane_basis
from metrology.sim.synth import SETUP_EFFECTS, HiddenEffect, synth_cloud, synth_run, typical_layouts

PLANE = Plane(TABLE5_PLANE[:3], TABLE5_PLANE[3])
N_POSES = 80
FOLDS = 5  # the CLI default

#: detectable ranges measured by benchmarks/study_diagnose.py on the typical pose set
#: (>= 90 % right cause and sensor over 10 seeded trials at both ends; see docs/readme_diagnose.md)
DETECTABLE = {
    "scale": (0.004, 0.016),  # gain error (unitless)
    "drift": (0.002, 0.03),  # mm/K
    "nonlinearity": (0.04, 0.3),  # mm (c3)
    "plane_form": (0.004, 0.05),  # mm (b_ss)
    "pose_error": (0.004, 0.03),  # mm (1 sigma per axis)
    "outliers": (0.06, 1.0),  # mm
}
#: magnitude check: estimate within K_SIGMA of its own standard error (plus model error)
K_SIGMA = 4.0


def run(effects, seed, n_poses=N_POSES):
    nominal, true = typical_layouts()
    export, truth = synth_run(np.random.default_rng(seed), true, PLANE, n_poses, effects)
    return Dataset(check(export, nominal), nominal, PLANE), truth


def small_case(seed=0, n_poses=30):
    ds, _ = run([], seed, n_poses)
    cov = covariates_for(ds, ds.layout)
    return ds, cov


# ---------------------------------------------------------------------------------------
# components


def all_components(ds, cov):
    names = ds.layout.names
    flags = np.zeros(ds.obs.d.shape, bool)
    flags[[2, 5], [1, 3]] = True
    rng = np.random.default_rng(5)
    return [
        Scale((1,), [2e-3], names=names), Incidence((2,), [0.03], names=names),
        Drift((0,), [0.004], names=names, variable="temp"), Drift((3,), [0.01], names=names, variable="time"),
        Nonlinearity((2,), [0.01, -0.02], names=names), PlaneForm((), rng.normal(0, 0.01, 5), names=names),
        PoseError((), rng.normal(0, 0.01, cov.n_poses), names=names, n_poses=cov.n_poses),
        Outliers((1, 3), [0.1, -0.2], names=names, flags=flags),
    ]


def test_component_jacobians_against_finite_differences():
    ds, cov = small_case()
    d0 = ds.export.d
    for c in all_components(ds, cov):
        J = c.jacobian(c.values, d0, cov)
        h = 1e-6
        for k in range(min(c.n_params, 6)):
            v = c.values.copy()
            v[k] += h
            fd = (c.evaluate(v, d0, cov) - c.evaluate(c.values, d0, cov)) / h
            np.testing.assert_allclose(J[..., k], fd, atol=1e-6, err_msg=c.label)
        fd0 = (c.evaluate(c.values, d0 + 1e-5, cov) - c.evaluate(c.values, d0, cov)) / 1e-5
        np.testing.assert_allclose(c.d_dd0(c.values, d0, cov), fd0, atol=1e-6, err_msg=c.label)


def test_components_act_only_on_their_sensors():
    ds, cov = small_case()
    for c in all_components(ds, cov):
        f = c.evaluate(c.values, ds.export.d, cov)
        if c.sensors and not isinstance(c, Outliers):
            others = [i for i in range(4) if i not in c.sensors]
            assert np.all(f[:, others] == 0), c.label
            assert np.any(f[:, list(c.sensors)] != 0), c.label


def test_components_evaluate_the_same_on_a_subset_of_poses():
    """A held-out fold is a subset of poses: a term must not depend on which poses are given
    (a drift referenced to the subset's first pose would shift every held-out prediction)."""
    ds, cov = small_case()
    d0 = ds.export.d
    idx = np.arange(3, cov.n_poses, 4)
    for c in all_components(ds, cov):
        if c.per_pose or isinstance(c, Outliers):
            continue
        np.testing.assert_allclose(c.evaluate(c.values, d0[idx], cov.select(idx)), c.evaluate(c.values, d0, cov)[idx],
                                   atol=1e-12, err_msg=c.label)


def test_name_clash_raises():
    nominal, _ = typical_layouts()
    with pytest.raises(ValueError, match="clash"):
        ExtendedModel(nominal, [Scale((1,), names=nominal.names), Scale((1,), names=nominal.names)])
    ExtendedModel(nominal, [Scale((1,), names=nominal.names), Scale((2,), names=nominal.names)])


def test_drift_without_temperature_raises():
    ds, cov = small_case()
    cov2 = Covariates(cov.time_h, np.full(cov.n_poses, np.nan), cov.cos_inc, cov.inv_nu, cov.spot_st, cov.range_mm)
    with pytest.raises(ValueError, match="no temp"):
        Drift((0,), [1.0], variable="temp").evaluate([1.0], ds.export.d, cov2)


# ---------------------------------------------------------------------------------------
# the extended fit


def test_base_fit_equals_estimators_lsq():
    ds, cov = small_case(1, 40)
    f = fit_model(ds.layout, ds.obs, cov, ds.layout.noise_mm, (), None, "lsq")
    cal = lsq(ds.layout, ds.obs)
    # Two solvers of one problem agree far inside the estimate's own uncertainty; how far
    # depends on their stopping rules and the wheels' LAPACK, so the bound is 1e-3 sigma.
    assert np.all(np.abs(f.theta - cal.theta) <= 1e-3 * cal.stderr)


@pytest.mark.parametrize("solver", ["lsq", "gn"])
def test_extended_fit_recovers_exact_effect_and_solvers_agree(solver):
    """No noise: the fit returns the hidden values exactly; Gauss-Newton = least_squares."""
    nominal, true = typical_layouts()
    quiet = SensorLayout(true.names, true.zero, true.direction, np.full(4, 1e-12), true.range_mm)
    export, _ = synth_run(np.random.default_rng(2), quiet, PLANE, 40, [HiddenEffect("nonlinearity", "L2", 0.02)])
    ds = Dataset(check(export, nominal), nominal, PLANE)
    cal = fit_model(nominal, ds.obs, covariates_for(ds, nominal), np.full(4, 0.003), (), None, "lsq")
    zero = nominal.zero + cal.theta[:, :3]
    from metrology.core.model import direction_from_tangent
    cov = covariates_for(ds, nominal.with_params(zero, direction_from_tangent(nominal.direction, cal.theta[:, 3:])))
    f = fit(nominal, ds.obs, cov, np.full(4, 0.003), [Nonlinearity((1,), names=nominal.names)], theta0=cal.theta,
            solver=solver)
    np.testing.assert_allclose(f.components[0].values, [0.01, 0.02], atol=2e-4)
    np.testing.assert_allclose(nominal.zero[1] + f.theta[1, :3], true.zero[1], atol=1e-4)
    assert np.nanmax(np.abs(f.residual)) < 1e-4


def test_pose_error_profiled_recovers_sigma():
    ds, truth = run([HiddenEffect("pose_error", None, 0.005)], 11)
    cov = covariates_for(ds, ds.layout)
    base = fit_model(ds.layout, ds.obs, cov, ds.layout.noise_mm, (), None, "lsq")
    f = fit(ds.layout, ds.obs, cov, ds.layout.noise_mm, [PoseError((), n_poses=N_POSES)], theta0=base.theta,
            solver="gn")
    e, se = f.components[0].values, f.components[0].stderr
    sig = np.sqrt(np.var(e, ddof=1) - np.mean(se**2))
    assert abs(sig - 0.005) < K_SIGMA * 0.005 / np.sqrt(2 * (N_POSES - 1)) + 5e-4
    assert f.chi2 / f.dof < 1.5


# ---------------------------------------------------------------------------------------
# hidden effects, found blind


def _check_named(d, effect, sensor, truth_rec):
    assert d.cause == effect, (d.cause, d.summary)
    if effect not in SETUP_EFFECTS:
        assert d.sensors == [sensor]
    h = d.heldout
    assert h["rms_ratio_concerned"] > 1.0 and h["p_heldout"] < 0.05
    params = d.named["params"]
    if effect == "scale":
        v = params["k"]
        assert abs(v["value"] - truth_rec["size"]) < K_SIGMA * v["stderr"]
    elif effect == "drift" and "rate_mm_per_K" in params:
        v = params["rate_mm_per_K"]
        assert abs(v["value"] - truth_rec["size"]) < K_SIGMA * v["stderr"]
    elif effect == "nonlinearity":
        for key, true in (("c2_mm", 0.5 * truth_rec["size"]), ("c3_mm", truth_rec["size"])):
            assert abs(params[key]["value"] - true) < K_SIGMA * params[key]["stderr"], key
    elif effect == "plane_form":
        for key in ("b_ss_mm", "b_st_mm", "b_tt_mm"):
            true = truth_rec["values"][key]
            assert abs(params[key]["value"] - true) < K_SIGMA * params[key]["stderr"] + 0.02 * abs(truth_rec["size"]), key
    elif effect == "pose_error":
        v = params["sigma_mm"]
        assert abs(v["value"] - truth_rec["size"]) < K_SIGMA * v["stderr"]
    elif effect == "outliers":
        flagged = d.named["flagged"]
        assert sorted(f["pose"] for f in flagged) == truth_rec["poses"]
        for f in flagged:
            assert abs(abs(f["gross_mm"]) - truth_rec["size"]) < K_SIGMA * f["stderr"] + K_SIGMA * 0.003


def _draw(effect, seed):
    """A hidden effect drawn blind: sensor and log-uniform size within the detectable range."""
    rng = np.random.default_rng([seed, 99, len(effect)])
    lo, hi = DETECTABLE[effect]
    size = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    sensor = None if effect in SETUP_EFFECTS else ["L1", "L2", "L3", "L4"][int(rng.integers(4))]
    return HiddenEffect(effect, sensor, size)


@pytest.mark.parametrize("effect", sorted(DETECTABLE))
def test_hidden_effect_named_blind(effect):
    he = _draw(effect, 0)
    ds, truth = run([he], 100 + len(effect))
    d = diagnose(ds, folds=FOLDS, sim_reps=1)
    _check_named(d, effect, he.sensor, truth["effects"][0])


#: the blind set's claim: inside the detectable ranges never a wrong catalogued cause, and the
#: right cause, sensor and magnitude in all but a few draws. The ranges' ends are where >= 90 %
#: of 10 trials was measured; inside them the rate is higher (the study: 100 % at most inner
#: sizes; this set: 30/30). At a true 95 %, 4 or more misses of 30 happen 6 % of the time; at
#: a true 90 %, 35 % (seeded, so a failure means the code changed, not chance)
BLIND_SEEDS = range(1, 6)
BLIND_MAX_MISSES = 3


@pytest.mark.slow
def test_hidden_effects_blind_set():
    """5 seeded draws per effect: misses are `none` or `unexplained` (at most 3 of 30), and a
    named catalogued cause is always the right one, on the right sensor, of the right size."""
    misses, wrong = [], []
    for effect in sorted(DETECTABLE):
        for seed in BLIND_SEEDS:
            he = _draw(effect, seed)
            ds, truth = run([he], 1000 * seed + len(effect))
            d = diagnose(ds, folds=FOLDS, sim_reps=1)
            if d.cause in ("none", "unexplained"):
                misses.append((he, d.cause, d.summary))
                continue
            try:
                _check_named(d, effect, he.sensor, truth["effects"][0])
            except AssertionError as exc:
                wrong.append((he, d.cause, d.sensors, str(exc)))
    assert not wrong, wrong
    assert len(misses) <= BLIND_MAX_MISSES, misses


def test_extended_simulation_predicts_measured_rms():
    """After the extension, the simulator reproduces the measured residual RMS of the sensor."""
    ds, _ = run([HiddenEffect("drift", "L2", 0.008)], 7)
    d = diagnose(ds, folds=FOLDS, sim_reps=2)
    disc = d.discrepancy
    meas, sim_b, sim_e = (np.array(disc[k]) for k in ("measured_residual_rms_mm", "simulated_base_residual_rms_mm",
                                                      "simulated_extended_residual_rms_mm"))
    assert d.cause == "drift" and d.sensors == ["L2"]
    # base simulation misses the excess on L2; the extended one predicts it (RMS of ~80 readings:
    # relative sampling error ~ 1/sqrt(2 * 75) = 8 %; 4 sigma)
    assert meas[1] > 1.3 * sim_b[1]
    assert abs(sim_e[1] / meas[1] - 1) < 4 * 0.08


def test_null_gives_none():
    """8 seeded null runs. The claim is a false-alarm rate <= 5 % (measured: 1 %); at 5 %, two or
    more alarms in 8 trials happen with probability 5.7 %, at the measured 1 % with 0.3 %."""
    causes = [diagnose(run([], 500 + s)[0], folds=FOLDS, sim_reps=1).cause for s in range(8)]
    assert sum(c != "none" for c in causes) <= 1, causes


@pytest.mark.slow
def test_null_false_alarm_rate_below_5_percent():
    causes = [diagnose(run([], 10_000 + s)[0], folds=FOLDS, sim_reps=1).cause for s in range(100)]
    assert sum(c != "none" for c in causes) <= 5, causes


@pytest.mark.parametrize("seed", range(2))
def test_out_of_catalogue_not_named_with_confidence(seed):
    ds, _ = run([HiddenEffect("periodic", "L3", 0.01)], 700 + seed)
    d = diagnose(ds, folds=FOLDS, sim_reps=1)
    assert d.cause == "unexplained" or d.confidence != "high", (d.cause, d.summary)


def test_scale_with_little_standoff_spread_is_reported_confounded_or_not_named():
    """A 0.2 % gain error on the typical pose set is mostly hidden in the beam geometry."""
    ds, _ = run([HiddenEffect("scale", "L1", 2e-3)], 31)
    d = diagnose(ds, folds=FOLDS, sim_reps=1)
    cand = {c["label"]: c for c in d.candidates}
    assert d.cause in ("none", "scale")
    assert cand["scale.L1"]["heldout_rms_ratio"] < 1.2


# ---------------------------------------------------------------------------------------
# the datum cloud: an independent measurement of the datum's form


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
    assert not d.datum_form["against_readings"]["agree"]


@pytest.mark.parametrize("with_pose_error", [True, False])
def test_form_agreement_is_calibrated_under_pose_errors(with_pose_error):
    """Readings with pose errors, a flat datum and a flat cloud: the readings' form fitted with
    the pose error agrees with the cloud's as chi-square(3) says (mean 3; 10 seeds: sd 0.8).
    A form fitted without it has standard errors ~1.8x too small (mean chi-square ~11)."""
    from metrology.diagnosis.datum import form_agreement, datum_form
    from metrology.core.model import direction_from_tangent, readings

    nominal, true = typical_layouts()
    chi2 = []
    for seed in range(10):
        rng = np.random.default_rng([31, seed])
        export, _ = synth_run(rng, true, PLANE, N_POSES, [HiddenEffect("pose_error", None, 0.02)])
        ds = Dataset(check(export, nominal), nominal, PLANE, synth_cloud(rng, PLANE))
        sigma = nominal.noise_mm
        base = fit_model(nominal, ds.obs, covariates_for(ds, nominal), sigma, (), None, "lsq")
        zero = nominal.zero + base.theta[:, :3]
        u = direction_from_tangent(nominal.direction, base.theta[:, 3:])
        cov = covariates_for(ds, nominal.with_params(zero, u))
        comps = [PlaneForm((), names=nominal.names)]
        if with_pose_error:
            comps.append(PoseError((), names=nominal.names, n_poses=N_POSES))
        pf = fit_model(nominal, ds.obs, cov, sigma, comps, base.theta)
        d0 = readings(zero, u, ds.obs.normal, ds.obs.offset)[0]
        chi2.append(form_agreement(datum_form(ds, zero, u, ds.obs, cov, d0, sigma), pf)["chi2"])
    if with_pose_error:
        assert np.mean(chi2) < 6.0, chi2
    else:  # the reason the diagnosis fits the form together with the named cause
        assert np.mean(chi2) > 6.0, chi2


def test_no_datum_cloud_no_form_section():
    ds, _ = run([], 3, 30)
    assert diagnose(ds, folds=3, sim_reps=1).to_dict()["datum_form"] is None


# ---------------------------------------------------------------------------------------
# the demo data set and the CLI


def test_fixture_hidden_is_diagnosed():
    from pathlib import Path

    from metrology.jobs.diagnose import diagnose_files

    here = DATA_DIR / "hidden"
    d = diagnose_files(here / "export.csv", here / "plane.json", here / "layout.toml", folds=FOLDS, sim_reps=1)
    assert d.cause != "none"
    assert d.named is not None and d.heldout["rms_ratio_concerned"] > 1.0


def test_cli_simulate_then_diagnose(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app
    from metrology.io.layout import save_layout

    nominal, _ = typical_layouts()
    save_layout(nominal, tmp_path / "layout.toml")
    (tmp_path / "plane.json").write_text(json.dumps({"normal": PLANE.normal.tolist(), "offset": PLANE.offset}))
    runner = CliRunner()
    r = runner.invoke(app, ["simulate", "--layout", str(tmp_path / "layout.toml"), "--plane",
                            str(tmp_path / "plane.json"), "--out", str(tmp_path / "x.csv"), "--effect", "outliers",
                            "--sensor", "L4", "--size", "0.1", "--poses", "60", "--seed", "3"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["diagnose", str(tmp_path / "x.csv"), "--plane", str(tmp_path / "plane.json"), "--layout",
                            str(tmp_path / "layout.toml"), "--json", "--folds", "3", "--report", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["cause"] == "outliers" and out["sensors"] == ["L4"]
    assert out["datum_form"] is None
    assert {"heldout", "candidates", "extended", "discrepancy"} <= set(out)
    assert all("p_heldout" in c and "p_insample" in c for c in out["candidates"])
    assert (tmp_path / "rep" / "residuals_named.png").exists()


def test_cli_errors_are_one_line_exit_2(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    runner = CliRunner()
    r = runner.invoke(app, ["diagnose", str(tmp_path / "nope.csv"), "--plane", str(tmp_path / "p.json"),
                            "--layout", str(tmp_path / "l.toml")])
    assert r.exit_code == 2
    assert "error:" in r.output and "Traceback" not in r.output
    nominal, _ = typical_layouts()
    from metrology.io.layout import save_layout

    save_layout(nominal, tmp_path / "layout.toml")
    (tmp_path / "plane.json").write_text(json.dumps({"normal": PLANE.normal.tolist(), "offset": PLANE.offset}))
    r = runner.invoke(app, ["simulate", "--layout", str(tmp_path / "layout.toml"), "--plane",
                            str(tmp_path / "plane.json"), "--out", str(tmp_path / "x.csv"), "--effect", "scale",
                            "--sensor", "L9", "--size", "0.001"])
    assert r.exit_code == 2 and "L9" in r.output
    assert not (tmp_path / "x.csv").exists()


def test_cli_simulate_writes_a_datum_cloud_that_diagnose_reads(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app
    from metrology.io.clouds import read_cloud
    from metrology.io.layout import save_layout

    nominal, _ = typical_layouts()
    save_layout(nominal, tmp_path / "layout.toml")
    (tmp_path / "plane.json").write_text(json.dumps({"normal": PLANE.normal.tolist(), "offset": PLANE.offset}))
    runner = CliRunner()
    base = ["simulate", "--layout", str(tmp_path / "layout.toml"), "--plane", str(tmp_path / "plane.json"),
            "--out", str(tmp_path / "x.csv"), "--effect", "plane_form", "--size", "0.01", "--seed", "5"]
    r = runner.invoke(app, base + ["--cloud", str(tmp_path / "datum.xyz")])
    assert r.exit_code == 2 and "datum.xyz" in r.output and ".ply" in r.output
    assert not (tmp_path / "x.csv").exists()
    r = runner.invoke(app, base + ["--cloud", str(tmp_path / "datum.ply")])
    assert r.exit_code == 0, r.output
    pts = read_cloud(tmp_path / "datum.ply")
    assert pts.shape == (4000, 3)
    r = runner.invoke(app, ["diagnose", str(tmp_path / "x.csv"), "--plane", str(tmp_path / "datum.ply"), "--layout",
                            str(tmp_path / "layout.toml"), "--folds", "3"])
    assert r.exit_code == 0, r.output
    assert "cause: plane_form" in r.output and "points, under the spots)" in r.output and "RMS in the base residuals" in r.output
    assert "the readings' plane_form" in r.output  # agrees or DISAGREES: the verdict is tested in the library
