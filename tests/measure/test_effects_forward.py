"""What diagnose learns goes to work (issue 50), on the independent forward simulator's data: a head
with a property of one sensor (metrology.sim.forward.properties) drawn in its calibration run and
in its production log alike; diagnose --out, calibrate --layout and measure --layout apply it."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.export import write_export
from metrology.io.layout import load_layout, save_layout
from metrology.measure.holes import Settings, measure_batch
from metrology.sim.forward import (Characteristic, HeadProperties, LogSpec, SensorProperty, draw_calibration, draw_head,
                                   make_panel, simulate_log)
from metrology.sim.forward.log_write import log_table, write_log_csv

runner = CliRunner()
GAIN = HeadProperties((SensorProperty(1, characteristic=Characteristic("gain", 30.0, 70.0, {"gain": -0.008})),))
TEMPCO = SensorProperty(2, tempco_mm_per_k=0.003, ref_temp_c=20.0)


def _write_run(tmp, name, head, props, seed):
    run = draw_calibration(np.random.default_rng(seed), head.true, props, 100, noise_mm=0.004, temp_span_c=(18.0, 22.0))
    write_export(run.export, tmp / f"{name}.csv")
    (tmp / f"{name}.plane.json").write_text(json.dumps({"normal": [float(v) for v in run.plane[0]],
                                                       "offset": float(run.plane[1])}))
    return tmp / f"{name}.csv", tmp / f"{name}.plane.json"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("effects")
    head = draw_head(np.random.default_rng(3), 4, noise_mm=0.004)
    save_layout(head.nominal, tmp / "nominal.toml")
    cal, plane = _write_run(tmp, "cal", head, GAIN, 5)
    r = runner.invoke(app, ["diagnose", str(cal), "--plane", str(plane), "--layout", str(tmp / "nominal.toml"),
                            "--out", str(tmp / "extended.toml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    r = runner.invoke(app, ["calibrate", str(cal), "--plane", str(plane), "--layout", str(tmp / "extended.toml"),
                            "--out", str(tmp / "ext_cal.toml"), "--json"])
    assert r.exit_code == 0, r.output
    r2 = runner.invoke(app, ["calibrate", str(cal), "--plane", str(plane), "--layout", str(tmp / "nominal.toml"),
                             "--out", str(tmp / "simple.toml")])
    assert r2.exit_code == 0, r2.output
    return {"tmp": tmp, "head": head, "cal": cal, "plane": plane, "diagnose": out, "calibrate": json.loads(r.stdout)}


def _errors(layout, head, props, holes=1500, seed=11, temperature=(20.0, 3.0, 0.05)):
    """Per-hole angle error (deg, measured normal against the true one) and U95 coverage."""
    spec = LogSpec(head.true, replace(layout, effects=None), make_panel("flat"), noise_mm=0.004, standoff_mm=42.0,
                   temperature_c=temperature, properties=props)  # production 8 mm nearer than the calibration's mean
    err, cover = [], []
    for ch in simulate_log(spec, seed, holes):
        t = measure_batch(layout, log_table(ch), Settings(min_radius_mm=math.inf)).columns
        n = np.column_stack([t.column(f"normal_{k}").to_numpy(zero_copy_only=False) for k in "xyz"]).astype(float)
        a = np.radians(t.column("angle_deg").to_numpy(zero_copy_only=False).astype(float))
        u = np.radians(t.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
        err.append(np.degrees(np.arccos(np.clip(-np.einsum("hi,hi->h", n, ch.normal_tcs), -1, 1))))
        cover.append(np.abs(a - ch.true_angle) <= u)
    return float(np.median(np.concatenate(err))), float(np.mean(np.concatenate(cover)))


def test_diagnose_out_writes_the_gain_with_its_covariance(files):
    lo = files["diagnose"]["layout_out"]
    assert lo["terms_written"] == ["scale.L2"] and lo["not_written"] == []
    lay = load_layout(files["tmp"] / "extended.toml")
    (k,) = lay.effects.components[0].values
    assert k == pytest.approx(-0.008, abs=0.001)
    assert lay.effects.cross.shape == (20, 1) and lay.effects.cov[0, 0] > 0


def test_calibrate_reestimates_the_term_and_says_the_poses_identify_it(files):
    (t,) = files["calibrate"]["effects"]
    assert t["label"] == "scale.L2" and t["identified"] is True
    assert t["params"]["k"]["value"] == pytest.approx(-0.008, abs=0.001)
    rows = [r for r in files["calibrate"]["certificate"]["parameters"] if r["parameter"] == "scale.L2 k"] \
        if "certificate" in files["calibrate"] else []
    assert all(r["U"] == pytest.approx(2 * r["u"]) for r in rows)


def test_measure_with_the_extended_layout_recovers_the_effect_free_error_and_coverage(files):
    head, tmp = files["head"], files["tmp"]
    # the reference: the same head without the property, calibrated on the same poses
    cal, plane = _write_run(tmp, "ref", head, HeadProperties(), 5)
    r = runner.invoke(app, ["calibrate", str(cal), "--plane", str(plane), "--layout", str(tmp / "nominal.toml"),
                            "--out", str(tmp / "ref.toml")])
    assert r.exit_code == 0, r.output
    ref, ref_cover = _errors(load_layout(tmp / "ref.toml"), head, None)
    simple, simple_cover = _errors(load_layout(tmp / "simple.toml"), head, GAIN)
    ext, ext_cover = _errors(load_layout(tmp / "ext_cal.toml"), head, GAIN)
    assert simple > 1.5 * ref and simple_cover < 0.8  # the gain is there to take
    assert ext <= 1.2 * ref
    assert abs(ext_cover - ref_cover) < 0.03 and ext_cover > 0.92


def test_diagnose_given_the_extended_layout_names_nothing_again(files):
    r = runner.invoke(app, ["diagnose", str(files["cal"]), "--plane", str(files["plane"]), "--layout",
                            str(files["tmp"] / "extended.toml"), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["cause"] == "none"


def test_diagnose_given_the_extended_layout_names_only_a_further_effect(files):
    tmp = files["tmp"]
    props = HeadProperties(GAIN.sensors + (TEMPCO,))
    cal, plane = _write_run(tmp, "more", files["head"], props, 6)
    r = runner.invoke(app, ["diagnose", str(cal), "--plane", str(plane), "--layout", str(tmp / "extended.toml"),
                            "--out", str(tmp / "extended2.toml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert [c["label"] for c in out["causes"]] == ["drift.L3@temp"]
    assert out["layout_out"]["carried_from_layout"] == ["scale.L2"]
    assert sorted(out["layout_out"]["terms_written"]) == ["drift.L3@temp", "scale.L2"]


def test_measure_refuses_a_log_without_the_temperature_a_term_needs(files, tmp_path):
    lay = load_layout(files["tmp"] / "extended.toml")
    from metrology.core.effects import Drift

    t = lay.effects
    drift = Drift((2,), [0.003], np.array([1e-4]), lay.names, variable="temp", ref=20.0)
    k = t.n_params + 1
    cov = np.eye(k) * 1e-10
    cov[:-1, :-1] = t.cov
    cross = np.zeros((20, k))
    cross[:, :-1] = t.cross
    from metrology.core.effects.terms import HeadTerms

    save_layout(replace(lay, effects=HeadTerms(t.components + (drift,), cov, cross)), tmp_path / "with_drift.toml")
    spec = LogSpec(files["head"].true, replace(lay, effects=None), make_panel("flat"), noise_mm=0.004)
    log = tmp_path / "log.csv"
    write_log_csv(simulate_log(spec, 1, 50), log, tmp_path / "truth.csv")
    text = log.read_text().splitlines()
    i = text[0].split(",").index("\"temperature_c\"")
    log.write_text("\n".join(",".join(c for j, c in enumerate(row.split(",")) if j != i) for row in text) + "\n")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(tmp_path / "with_drift.toml")])
    assert r.exit_code == 2
    assert "temperature_c" in r.output and "drift.L3@temp" in r.output and len(r.output.strip().splitlines()) == 1


def test_simulate_log_draws_the_head_the_extended_layout_describes(files, tmp_path):
    ext = files["tmp"] / "ext_cal.toml"
    log, truth = tmp_path / "log.parquet", tmp_path / "truth.parquet"
    r = runner.invoke(app, ["simulate-log", "--layout", str(ext), "--true-layout", str(ext), "--out", str(log),
                            "--truth", str(truth), "--holes", "800", "--standoff-mm", "42", "--json"])
    assert r.exit_code == 0, r.output
    props = json.loads(r.stdout)["spec"]["properties"]
    assert props["sensors"][0]["characteristic"]["gain"] == pytest.approx(-0.008, abs=0.001)
    import pyarrow.parquet as pq

    results = {}
    for name, lay in (("extended", ext), ("simple", files["tmp"] / "simple.toml")):
        out = tmp_path / f"{name}.parquet"
        r = runner.invoke(app, ["measure", str(log), "--layout", str(lay), "--out", str(out)])
        assert r.exit_code in (0, 1), r.output
        a = pq.read_table(out).to_pandas().set_index("hole_id")
        t = pq.read_table(truth).to_pandas().set_index("hole_id")
        results[name] = float(np.median(np.abs(a["angle_deg"] - t.loc[a.index, "true_angle_deg"])))
    assert results["extended"] < 0.75 * results["simple"]


def test_the_drift_watch_raises_no_alarm_for_a_temperature_coefficient_the_layout_explains():
    """A head whose L2 zero follows the shop's temperature at 3.3 um/K: the simple layout's drift
    watch reads it as drift; with the coefficient in the layout the redundant reading stays in control."""
    from metrology.core.effects import Drift
    from metrology.core.effects.terms import HeadTerms
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.io.holelog import batch_of
    from metrology.measure.run import Feed, Watch
    from metrology.sim.forward import perturb_layout

    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    true = perturb_layout(np.random.default_rng(4), nominal, zero_error_mm=(0.002, 0.01), direction_error_deg=(0.001, 0.01))
    cov = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    simple = nominal.with_params(nominal.zero, nominal.direction, covariance=cov)
    term = Drift((1,), [0.0033], np.array([1e-4]), nominal.names, variable="temp", ref=20.0)
    extended = replace(simple, effects=HeadTerms((term,), [[1e-8]], np.zeros((20, 1))))
    props = HeadProperties((SensorProperty(1, tempco_mm_per_k=0.0033, ref_temp_c=20.0),))
    spec = LogSpec(true, simple, make_panel("flat"), temperature_c=(20.0, 3.0, 0.05), properties=props)
    alarms = {}
    for name, lay in (("simple", simple), ("extended", extended)):
        watch = Watch(lay.names)
        for c in simulate_log(spec, 2, 4000, chunk_holes=1000):
            t = batch_of(log_table(c), lay.names)
            watch.feed(Feed.of(measure_batch(lay, t, Settings(min_radius_mm=np.inf)), "sim", first_row=int(c.hole[0])))
        watch.finish()
        alarms[name] = watch.alarms
    assert len(alarms["simple"]) >= 1 and alarms["extended"] == []


def test_validate_judges_each_layout_on_its_own_readings(files):
    """A held-out run of the head with the gain: the extended layout's normals (its term removed from
    the readings) deviate less from the datum's than the simple layout's."""
    tmp = files["tmp"]
    cal, plane = _write_run(tmp, "held", files["head"], GAIN, 9)
    r = runner.invoke(app, ["validate", str(cal), "--plane", str(plane), "--layout", str(tmp / "ext_cal.toml"),
                            "--layout-before", str(tmp / "simple.toml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    mean = {k: v["mean_deg"] for k, v in out["layouts"].items()}
    assert mean["layout"] < 0.8 * mean["layout_before"]
