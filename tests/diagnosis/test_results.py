"""The typed results: a cause, its size and rivals, and the JSON made from them at the edge."""

from metrology.diagnosis.results import Cause, Confidence, Outcome, Rival, Size


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
