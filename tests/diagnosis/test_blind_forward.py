"""Blind diagnosis of cases drawn by the independent forward simulator (issues 12 and 15).

The fast subset draws a few nulls and one clear case per family (size at 90 % of the family's
drawn range, 80 poses) and runs them through the public file contract (``write_case`` ->
``diagnose_files``, what ``metro diagnose`` calls). The full study is ``-m slow``.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.jobs.diagnose import diagnose_files
from metrology.report.diagnose import report_text
from metrology.sim.forward import FAMILIES, draw_case, write_case
from tests.diagnosis.helpers import study_blind

CLEAR = ("pose_error", "scale", "nonlinearity", "drift", "incidence", "plane_form", "outliers")
ALL_SENSORS = ("pose_error", "plane_form")


def _diagnosis(case, tmp_path):
    paths = write_case(case, tmp_path)
    return diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])


def _diagnose(case, tmp_path):
    return _diagnosis(case, tmp_path).to_dict()


def _clear(family, seed=11):
    lo, hi = FAMILIES[family].size_range
    size = 5 if family == "outliers" else lo + 0.9 * (hi - lo)
    # a gain error is named only where it is told from crosstalk, and at 14 deg tilts the
    # sensors' distances move together too much for 0.18 mm (detectable there: 0.24 mm)
    tilt = 25.0 if family == "scale" else 14.0
    return draw_case(np.random.default_rng([seed]), family, size=size, n_poses=80, tilt_max_deg=tilt)


# a second null draw runs the same path as the first: with the slow tests (issue 51 item 15: the default run's time)
@pytest.mark.parametrize("seed", [11, pytest.param(12, marks=pytest.mark.slow)])
def test_null_names_no_cause(seed, tmp_path):
    case = draw_case(np.random.default_rng([seed]), "none", n_poses=80)
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "none", res["summary"]
    assert not res.get("causes")


#: families a dedicated default test names on forward-simulated data through ``write_case`` (pose_error:
#: test_families.py's orientation-only head; plane_form: test_plane_form_family.py; outliers: test_families.py's
#: two causes): their clear case here runs with the slow tests (issue 51 item 15: the default run's time)
NAMED_ELSEWHERE = ("pose_error", "plane_form", "outliers")


@pytest.mark.parametrize("family", [pytest.param(f, marks=pytest.mark.slow) if f in NAMED_ELSEWHERE else f
                                    for f in CLEAR])
def test_clear_case_names_cause_and_sensor(family, tmp_path):
    case = _clear(family)
    assert case.family == family and len(case.effects) == 1
    diag = _diagnosis(case, tmp_path)
    res = diag.to_dict()
    assert res["cause"] == family, res["summary"]
    # the steps table marks the steps whose cause is named (a later step's can be turned down),
    # and the text report says which are not
    assert {st["added"] for st in res["steps"][1:] if st["named"]} == {c["label"] for c in res["causes"]}
    assert report_text(diag).count("(not named)") == sum(not st["named"] for st in res["steps"][1:])
    if family not in ALL_SENSORS:
        assert set(res["sensors"]) == set(case.sensors)
    if family in ("scale", "drift", "incidence"):  # above what these poses detect, as reported
        assert case.effects[0].size > res["detectable"][family]["sensors"][case.sensors[0]]


def test_crosstalk_is_never_a_confident_gain_error(tmp_path):
    # crosstalk (outside the catalogue) at 14 deg tilts: the gain error that mimics it is named
    # only as ambiguous, with the crosstalk it cannot be told from listed as its rival and the
    # command that designs poses to separate them (issue 30, item 5)
    case = draw_case(np.random.default_rng([11]), "crosstalk", size=0.09, n_poses=80)
    res = _diagnose(case, tmp_path)
    if res["causes"]:
        assert res["confidence"] == "ambiguous", res["summary"]
        rivals = [r for c in res["causes"] for r in c.get("rivals", [])]
        src = case.effects[0].shape["source"]
        assert any(r["family"] == "crosstalk" and r["label"].endswith("<-" + src) for r in rivals), rivals
        assert "metro plan --separate scale" in res["summary"]
    else:
        assert res["cause"] in ("none", "unexplained"), res["summary"]


def test_study_scores_a_cause_named_beside_the_right_one_as_wrong():
    """A single draw named with its cause *and* another (seed-105 drift 13: drift and incidence
    on L4, ``high``) is not a right ``high``, and the study counts the extra cause."""
    mod = study_blind()
    truth = [{"family": "drift", "sensors": ["L4"], "size": 0.05, "inside": True, "detectable": 0.01}]
    rec = {"kind": "single", "family": "drift", "truth": truth, "cause": "drift", "sensors": ["L4"],
           "confidence": "high", "sizes": {"drift": None}}
    recs = [dict(rec, named=[["drift", ["L4"]], ["incidence", ["L4"]]]), dict(rec, named=[["drift", ["L4"]]]),
            dict(rec, named=[["drift", ["L4"]]], confidence="moderate")]
    s = mod.summarize(recs, mod.detectable_ranges())
    assert s["families"]["drift"]["right"] == 3 and s["families"]["drift"]["extra_named"] == 1
    assert s["high_precision"] == {"n": 2, "right": 1} and s["moderate_named"] == {"n": 1, "right": 1}
    assert "a wrong cause named beside the right one: drift 1" in mod.report(s)


@pytest.fixture(scope="module")
def study():
    mod = study_blind()
    _, summary = mod.run_study(draws=20, nulls=200, pairs=32, seed=0, jobs=1, progress=False)
    return summary


@pytest.mark.slow
def test_study_right_inside_detectable_range(study):
    for fam, r in study["families"].items():
        assert r["n"] >= 20
        assert r["right_detectable"] >= 0.95 * r["n_detectable"], (fam, r)


@pytest.mark.slow
def test_study_null_false_cause_rate(study):
    """Nulls: no catalogued cause ever; a verdict other than `none` (``unexplained``: the noise battery refuses
    the noise model at its level, ALPHA_BATTERY = 0.01) at that level's rate. A rate of 1 % on 200 draws gives 3 or
    more 32 % of the time (seed 0 gives 3 of 200, battery p 0.0016-0.007, the same before the open search), so the
    count is held to the binomial's 99th percentile at 1 % (6), not to 1 % itself."""
    from scipy.stats import binom

    from metrology.diagnosis.rules import ALPHA_BATTERY

    n = study["null"]
    assert n["n"] >= 200
    assert n["named_catalogued"] == 0, n
    assert n["false_cause"] <= binom.ppf(0.99, n["n"], ALPHA_BATTERY), n


@pytest.mark.slow
def test_study_out_of_catalogue_never_catalogued(study):
    """Out-of-catalogue draws (crosstalk, periodic) are never named a catalogued cause with confidence high or
    moderate (issue 54's goal). A gain error that crosstalk ties is named ``ambiguous`` with the crosstalk as its
    rival, by design (test_crosstalk_is_never_a_confident_gain_error): seed 0 names 15 of 40 so, all ambiguous."""
    assert study["ooc"]["n"] >= 40
    assert study["ooc"]["catalogued_confident"] == 0, study["ooc"]


@pytest.mark.slow
def test_study_pairs_both_named(study):
    p = study["pairs"]  # issue 15: pairs at sizes above each family's detectable size
    assert p["n_detectable"] >= 10, p
    assert p["both_right_detectable"] >= 0.9 * p["n_detectable"], p
    assert p["wrong_added"] <= 0.02 * p["n"], p
