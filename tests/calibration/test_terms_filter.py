"""The EKF and IEKF with their state extended by a layout's head terms (metrology.calibration.terms_filter),
on calibration runs of the independent forward simulator (metrology.sim.forward) drawing a head
with a gain on L2 and a temperature coefficient on L3."""

import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.calibration.calibrate import calibrate_dataset
from metrology.calibration.dataset import load_dataset
from metrology.core.effects import Drift, Scale
from metrology.core.effects.terms import HeadTerms
from metrology.io.export import write_export
from metrology.io.layout import layout_to_toml, load_layout, save_layout
from metrology.sim.forward import Characteristic, HeadProperties, SensorProperty, draw_calibration, draw_head

runner = CliRunner()
GAIN, RATE = -0.008, 0.003
PROPS = HeadProperties((SensorProperty(1, characteristic=Characteristic("gain", 30.0, 70.0, {"gain": GAIN})),
                        SensorProperty(2, tempco_mm_per_k=RATE, ref_temp_c=20.0)))


def _dataset(tmp, span=(18.0, 22.0), seed=5):
    head = draw_head(np.random.default_rng(3), 4, noise_mm=0.004)
    run = draw_calibration(np.random.default_rng(seed), head.true, PROPS, 100, noise_mm=0.004, temp_span_c=span)
    write_export(run.export, tmp / "cal.csv")
    (tmp / "plane.json").write_text(json.dumps({"normal": [float(v) for v in run.plane[0]],
                                                "offset": float(run.plane[1])}))
    lay = head.nominal
    # the layout's terms: starting values away from the truth, a wide stated covariance (a prior, not the answer)
    terms = HeadTerms((Scale((1,), [0.0], np.array([0.005]), lay.names),
                       Drift((2,), [0.0], np.array([0.005]), lay.names, variable="temp", ref=20.0)),
                      np.diag([0.005 ** 2, 0.005 ** 2]), np.zeros((20, 2)))
    base = np.diag(np.tile([2.0 ** 2] * 3 + [0.1 ** 2] * 2, 4))
    save_layout(replace(lay, effects=terms, covariance=base), tmp / "extended.toml")
    return load_dataset(tmp / "cal.csv", tmp / "plane.json", tmp / "extended.toml"), head


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("terms_filter")
    ds, head = _dataset(tmp)
    return tmp, head, {m: calibrate_dataset(ds, m) for m in ("lsq", "ekf", "iekf")}


def _terms(rep):
    return {t["label"]: (t["params"][next(iter(t["params"]))]["value"], t["params"][next(iter(t["params"]))]["stderr"],
                         t["identified"]) for t in rep.terms.to_dict()}


#: how far (in the larger stated sigma) a filter's term may sit from least squares': the IEKF is the MAP
#: estimate (0.1 sigma measured on seeds 5-10); the one-pass EKF, linearised at the base least-squares chart
#: (terms_filter.LINEARISE), 0.03-0.27 sigma on this head (seeds 5-10; at its running estimate from the nominal
#: 0.15-2.41 sigma); on the six heads of benchmarks/results/study_terms_filter.md up to 1.97 sigma (a gain)
AGREE_SIGMA = {"iekf": 0.5, "ekf": 0.5}


@pytest.mark.parametrize("method", ["ekf", "iekf"])
def test_the_filters_terms_agree_with_least_squares_and_the_truth(fits, method):
    _, _, reps = fits
    lsq, got = _terms(reps["lsq"]), _terms(reps[method])
    assert set(got) == {"scale.L2", "drift.L3@temp"}
    for label, truth in (("scale.L2", GAIN), ("drift.L3@temp", RATE)):
        v, se, ident = got[label]
        vl, sel, _ = lsq[label]
        assert ident
        assert 0 < se < 0.1 * abs(truth)  # the poses inform it: far below the prior's 0.005
        assert abs(v - vl) < AGREE_SIGMA[method] * max(se, sel)  # the same data, the same estimate
        assert abs(v - truth) < 3 * se


@pytest.mark.parametrize("method", ["iekf"])
def test_the_filters_zero_points_are_those_of_least_squares(fits, method):
    tmp, head, reps = fits
    dz = np.abs(reps[method].layout.zero - reps["lsq"].layout.zero)
    se = reps["lsq"].calibration.stderr[:, :3]
    assert np.all(dz < 2 * se + 1e-4)
    err = np.abs(reps[method].layout.zero - head.true.zero)
    assert np.all(err < 4 * reps[method].calibration.stderr[:, :3] + 1e-3)


def test_a_coefficient_calibrated_at_one_temperature_is_carried_by_the_filter(tmp_path):
    ds, _ = _dataset(tmp_path, span=(20.0, 20.0))
    t = {d["label"]: d for d in calibrate_dataset(ds, "ekf").terms.to_dict()}
    drift = t["drift.L3@temp"]
    assert drift["identified"] is False and "does not change" in drift["why_not"]
    assert drift["params"]["rate_mm_per_K"]["value"] == 0.0 and drift["params"]["rate_mm_per_K"]["stderr"] == 0.005
    assert t["scale.L2"]["identified"] is True


def test_calibrate_method_ekf_writes_the_terms_with_their_covariance(fits):
    tmp, _, reps = fits
    out = tmp / "ekf.toml"
    r = runner.invoke(app, ["calibrate", str(tmp / "cal.csv"), "--plane", str(tmp / "plane.json"), "--layout",
                            str(tmp / "extended.toml"), "--method", "ekf", "--out", str(out), "--json"])
    assert r.exit_code in (0, 1), r.output
    eff = {t["label"]: t for t in json.loads(r.stdout)["effects"]}
    assert eff["scale.L2"]["identified"] and eff["scale.L2"]["params"]["k"]["value"] == pytest.approx(GAIN, abs=0.001)
    back = load_layout(out)
    assert back.effects.param_names == ("scale.L2.k", "drift.L3@temp.rate_mm_per_K")
    assert np.all(np.diag(back.effects.cov) > 0) and back.effects.cross.shape == (20, 2)
    full = np.block([[back.covariance, back.effects.cross], [back.effects.cross.T, back.effects.cov]])
    assert np.linalg.eigvalsh(full).min() > -1e-9 * np.abs(full).max()
    assert layout_to_toml(back)  # writes back


def test_the_papers_filter_refuses_an_extended_layout(fits):
    tmp = fits[0]
    r = runner.invoke(app, ["calibrate", str(tmp / "cal.csv"), "--plane", str(tmp / "plane.json"), "--layout",
                            str(tmp / "extended.toml"), "--method", "ekf_paper"])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
    assert "effect terms (scale.L2, drift.L3@temp)" in r.output and "ekf or iekf" in r.output


def test_the_filters_with_terms_take_the_base_filters_keywords(fits, tmp_path):
    """``stderr`` and ``Q`` as :func:`metrology.calibration.estimators.ekf` / ``iekf`` take them: the
    residual-scaled covariance is least squares' (the same data, the same estimate); process noise
    widens what the EKF states; the IEKF refuses process noise, any filter an unknown ``stderr``."""
    import inspect

    from metrology.calibration.estimators import ekf, iekf
    from metrology.calibration.terms_filter import filter_with_terms

    got = inspect.signature(filter_with_terms).parameters
    for base in (ekf, iekf):
        for name, p in inspect.signature(base).parameters.items():
            if name not in ("nominal", "obs"):
                assert name in got and got[name].default == p.default or name == "P0_sigma", name
    ds, _ = _dataset(tmp_path)
    lsq = _terms(fits[2]["lsq"])
    rep = calibrate_dataset(ds, "iekf", stderr="residual")
    res, stated = _terms(rep), _terms(fits[2]["iekf"])
    scatter = rep.calibration.sigma_mm  # each sensor's own residual scatter (least squares pools the sensors')
    for label, i in (("scale.L2", 1), ("drift.L3@temp", 2)):
        assert 0.5 * 0.004 < scatter[i] < 2 * 0.004
        # the stated noise's standard error scaled by the residuals' scatter (the weak prior aside)
        assert res[label][1] == pytest.approx(stated[label][1] * scatter[i] / 0.004, rel=0.03)
        assert res[label][1] == pytest.approx(lsq[label][1], rel=0.15)
        assert res[label][0] == pytest.approx(stated[label][0], abs=1e-12)  # the estimate is the filter's
    base = _terms(fits[2]["ekf"])
    noisy = _terms(calibrate_dataset(ds, "ekf", Q=1e-8))
    for label in ("scale.L2", "drift.L3@temp"):
        assert noisy[label][1] > 1.5 * base[label][1]
    with pytest.raises(ValueError, match="iekf takes no process noise"):
        calibrate_dataset(ds, "iekf", Q=1e-8)
    with pytest.raises(ValueError, match="stderr 'both'"):
        calibrate_dataset(ds, "ekf", stderr="both")
