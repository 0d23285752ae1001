"""The typed results: a cause, its size and rivals, and the JSON made from them at the edge."""

import json

import numpy as np
import pytest

from metrology.diagnosis.results import (Cause, Confidence, Confounding, Discrepancy, HeldOutFigures, Outcome, Rival, Size,
                                         StepFigures)


def test_a_cause_round_trips_to_its_json_keys_in_order():
    desc = {"component": "scale", "label": "scale.L3", "sensors": ["L3"],
            "params": {"k": {"value": 1e-3, "unit": "1", "stderr": 1e-4}},
            "cause": "scale", "size": Size(0.04, 0.004, "mm", "ptp", 0.003, 0.002),
            "heldout_gain_chi2": 68.8, "p_heldout_given_others": 0.0049, "p_insample": 1e-6, "step": 1}
    r = Rival("crosstalk.L3<-L2", "crosstalk", "scale.L3", False, None, "metro plan --separate scale")
    c = Cause.from_description(desc, [r])
    assert c.size == Size(0.04, 0.004, "mm", "ptp", 0.003, 0.002) and c.rivals == (r,)
    out = c.to_dict()
    assert list(out) == list(desc) + ["rivals"]  # the description's order, rivals only where there is one
    assert {k: out[k] for k in desc} == {**desc, "size": {"value": 0.04, "stderr": 0.004, "unit": "mm", "meaning": "ptp",
                                                          "stderr_fit": 0.003, "model_spread": 0.002}}
    assert c.detail["size"] is None  # the typed keys hold their place in the order, their values are attributes
    assert out["rivals"] == [r.to_dict()] and "rivals" not in Cause.from_description(desc).to_dict()


def test_outcome_and_confidence_are_string_enums():
    assert Confidence("ambiguous") is Confidence.AMBIGUOUS and Confidence.HIGH == "high"
    assert Outcome("none") is Outcome.NONE
    import json

    assert json.dumps({"c": Confidence.LOW}) == '{"c": "low"}'


# -- the diagnosis holds typed results; the JSON made from them keeps its keys ---------------------

@pytest.fixture(scope="module")
def hidden(hidden_diagnosis):
    """The README's ``--explain`` example: the bundled run that hides a temperature drift on L3
    (diagnosed once a run, tests/conftest.py)."""
    return hidden_diagnosis


def test_the_diagnosis_holds_typed_results_not_dicts(hidden):
    from metrology.diagnosis.detectable import Detectable
    from metrology.diagnosis.stats import NoiseTests, PairTest, SensorTests, Trend

    d = hidden
    assert d.cause == "drift" and isinstance(d.named.size, Size)
    assert d.named.size.unit == "mm" and d.named.size.stderr_fit is not None and d.named.size.model_spread >= 0.0
    assert d.named.size.stderr >= d.named.size.stderr_fit  # the members' spread added in quadrature
    from metrology.diagnosis.results import Param

    rate = d.named.params["rate_mm_per_K"]  # the drift's parameters: Param, not dicts
    assert all(isinstance(v, Param) for v in d.named.params.values()) and rate.unit == "mm/K" and rate.stderr > 0.0
    assert d.to_dict()["causes"][0]["params"]["rate_mm_per_K"] == rate.to_dict()
    assert isinstance(d.heldout, HeldOutFigures) and d.heldout.model == "drift.L3@temp"
    assert d.heldout.rms_ratio_concerned > 1.0 and 0.0 < d.heldout.extended_normal_rad < d.heldout.base_normal_rad
    assert isinstance(d.discrepancy, Discrepancy) and d.discrepancy.extended_model == "drift.L3@temp"
    assert d.discrepancy.sensors == ["L1", "L2", "L3", "L4"] and len(d.discrepancy.simulated_extended_residual_rms_mm) == 4
    assert all(isinstance(s, StepFigures) for s in d.steps) and d.steps[0].added is None
    assert [s.added for s in d.steps[1:]] == ["drift.L3@temp"] and d.steps[1].named is True
    assert all(isinstance(c, Confounding) for c in d.confounding)
    assert isinstance(d.tests_base, NoiseTests) and isinstance(d.tests_base.sensors["L3"], SensorTests)
    assert all(isinstance(t, PairTest) for t in d.tests_base.pairs.values()) and d.tests_base.pairs
    assert d.tests_base.sensors["L3"].chi2 / d.tests_base.sensors["L3"].dof > 1.0
    cells = [t for row in d.structure_base.values() for t in row.values()]
    assert cells and all(isinstance(t, Trend) and 0.0 <= t.r2 <= 1.0 and 0.0 <= t.p <= 1.0 for t in cells)
    assert d.structure_base["temp_c"]["L3"].p < 1e-3  # the drift shows against temperature on L3
    assert d.detectable and all(isinstance(x, Detectable) for x in d.detectable.values())
    assert d.detectable["drift"].sensors["L3"] > 0.0 and d.detectable["drift"].member["L3"].startswith("drift.L3")


def test_the_json_of_the_typed_results_keeps_its_keys(hidden):
    out = json.loads(json.dumps(hidden.to_dict()))
    assert list(out["heldout"]) == ["folds", "base_rms_mm", "base_normal_deg", "model", "extended_rms_mm", "rms_ratio",
                                    "base_rms_concerned_mm", "extended_rms_concerned_mm", "rms_ratio_concerned",
                                    "extended_normal_deg", "normal_ratio", "p_heldout"]
    assert out["heldout"]["base_normal_deg"] == float(np.rad2deg(hidden.heldout.base_normal_rad))
    assert list(out["discrepancy"]) == [
        "sensors", "stated_noise_mm", "measured_residual_rms_mm", "simulated_base_residual_rms_mm",
        "measured_heldout_normal_deg", "simulated_base_heldout_normal_deg", "simulated_base_heldout_normal_sd_deg",
        "sim_reps", "simulated_extended_residual_rms_mm", "simulated_extended_heldout_normal_deg",
        "simulated_extended_heldout_normal_sd_deg", "extended_model"]
    assert [list(s) for s in out["steps"]] == [
        ["added", "model", "residual_rms_mm", "heldout_rms_mm"],
        ["added", "model", "residual_rms_mm", "heldout_rms_mm", "p_heldout", "heldout_gain_chi2", "named"]]
    assert list(out["causes"][0]["size"]) == ["value", "stderr", "unit", "meaning", "stderr_fit", "model_spread"]
    assert all(list(v) == ["sensors", "member", "meaning"] for v in out["detectable"].values())
    assert all(list(c) == ["r2", "p"] for row in out["structure"].values() for c in row.values())
    t = out["tests"]["base"]
    assert all(list(s) == ["chi2", "dof", "sigma_est_mm", "p_chi2", "p_whiteness", "p_normality"]
               for s in t["sensors"].values())
    assert all(list(p) == ["r", "p"] for p in t["pairs"].values())


def test_the_optional_figures_are_left_out_of_the_json_where_nothing_is_named():
    h = HeldOutFigures(5, 0.002, 1e-4)
    assert h.to_dict() == {"folds": 5, "base_rms_mm": 0.002, "base_normal_deg": float(np.rad2deg(1e-4))}
    d = Discrepancy(["L1"], [0.003], [0.004], [0.003], 1e-4, 2e-4, 1e-5, 2)
    assert "extended_model" not in d.to_dict() and d.to_dict()["simulated_base_heldout_normal_deg"] == float(
        np.rad2deg(2e-4))
    assert StepFigures(None, "base", [0.003], 0.003).to_dict() == {"added": None, "model": "base",
                                                                    "residual_rms_mm": [0.003], "heldout_rms_mm": 0.003}


def test_a_confounding_note_carries_its_own_figure():
    tie = Confounding(("scale.L3", "crosstalk.L3<-L2"), "cannot tell")
    assert tie.to_dict() == {"between": ["scale.L3", "crosstalk.L3<-L2"], "p_separation": None, "message": "cannot tell"}
    corr = Confounding(("drift.L2.rate", "dz_L2"), "correlated", correlation=0.97)
    assert list(corr.to_dict()) == ["between", "correlation", "message"] and corr.to_dict()["correlation"] == 0.97


def test_the_model_spread_is_added_to_a_size_not_to_a_dict():
    from types import SimpleNamespace

    from metrology.diagnosis.extension import with_model_spread

    s = Size(0.05, 0.004, "mm", "ptp")
    chosen = SimpleNamespace(label="scale.L1")
    assert with_model_spread(None, chosen, [], None, None) is None
    assert with_model_spread(Size(0.05, None, "mm", "ptp"), chosen, [], None, None) == Size(0.05, None, "mm", "ptp")
    got = with_model_spread(s, chosen, [], None, None)  # no rival member: the spread is 0, both parts said
    assert isinstance(got, Size) and (got.stderr, got.stderr_fit, got.model_spread) == (0.004, 0.004, 0.0)
    assert list(got.to_dict()) == ["value", "stderr", "unit", "meaning", "stderr_fit", "model_spread"]
