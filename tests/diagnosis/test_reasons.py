"""The verdict's trail: the rules that made it, recorded where they fired, and the words made from it."""

from __future__ import annotations

import json

import pytest

from metrology.io.data import DATA_DIR

H = DATA_DIR / "hidden"


@pytest.fixture(scope="module")
def hidden(hidden_diagnosis):
    """The bundled hidden run (a temperature drift on L3), diagnosed once a run (tests/conftest.py)."""
    return hidden_diagnosis


def test_the_hidden_drift_has_its_trail_in_the_order_the_rules_fired(hidden):
    from metrology.diagnosis import rules

    trail = [(r.rule, r.name, str(r.decided), r.concerns[:1], r.step) for r in hidden.reasons]
    assert trail == [
        (2, "significant", "chosen", ("drift.L3@temp",), 1),  # step 1 takes the drift
        (2, "significant", "nothing significant", (), 2),  # step 2 finds nothing more: the selection stops
        (10, "needed_given_others", "needed", ("drift.L3@temp",), 1),  # the verdict: needed
        (11, "explains_sensors", "explains its sensors", ("drift.L3@temp",), 1),  # L3 then noise
        (16, "confidence_of", "confidence", ("drift.L3@temp",), None),
    ]
    chosen, _, needed, explains, confidence = hidden.reasons
    # each entry carries its statistic against the rule's own threshold
    assert chosen.threshold == rules.ALPHA_HELDOUT and chosen.value < rules.ALPHA_HELDOUT and chosen.gain > 0
    assert needed.value == pytest.approx(hidden.causes[0].p_heldout_given_others)
    assert needed.gain == pytest.approx(hidden.causes[0].heldout_gain_chi2)
    assert explains.concerns == ("drift.L3@temp", "L3") and explains.value >= rules.ALPHA_BATTERY
    assert confidence.outcome == hidden.confidence == "high"
    # --json carries them
    d = hidden.to_dict()
    assert [r["rule"] for r in d["reasons"]] == [2, 2, 10, 11, 16]
    assert d["reasons"][0]["concerns"] == ["drift.L3@temp"] and d["reasons"][-1]["outcome"] == "high"
    json.dumps(d["reasons"])  # JSON-ready as they are


def _judgement(reasons, **kw):
    from metrology.diagnosis.judge import Judgement

    return Judgement(reasons=tuple(reasons), **kw)


def _tests(consistent=True):
    from metrology.diagnosis.stats import NoiseTests, SensorTests

    sensors = {"L1": SensorTests(10.0, 10, 0.003, 0.44, 0.5, None)}
    return NoiseTests(sensors, {}, 1, 0.5 if consistent else 1e-6, consistent, ((0.5, {0}),))


def test_the_summary_is_made_from_the_trail_not_re_derived():
    """A sole cause turned down: the summary's figures are those of its reasons (the step's
    held-out p of rule 2, the gain and p against the base model of rule 10)."""
    from metrology.diagnosis.results import Confidence, Decision, Outcome, Reason
    from metrology.diagnosis.decide import verdict_summary

    why = [Reason(2, "significant", Decision.CHOSEN, ("drift.L2@time",), "p_heldout", 0.031, 0.05, 7.5, 1),
           Reason(2, "significant", Decision.NOTHING_SIGNIFICANT, (), "candidates significant", 0, 0.05, step=2),
           Reason(10, "needed_given_others", Decision.DROPPED, ("drift.L2@time",), "p_heldout_against_base", 0.2,
                  0.05, 1.25, 1, Confidence.LOW)]
    v = _judgement(why, cause=Outcome.NONE, confidence=Confidence.LOW)
    s = verdict_summary(v, _tests())
    assert "drift.L2@time was selected (held-out p = 0.031 at its step)" in s
    assert "held-out chi-square gain 1.25, p = 0.2), so it is not named" in s
    # without the rule-10 entry the same judgement is not said to have dropped anything
    s2 = verdict_summary(_judgement(why[:2], cause=Outcome.NONE, confidence=Confidence.LOW), _tests())
    assert "not named" not in s2 and "no candidate gives a significant held-out gain" in s2
    # the datum's rule 17 appends its sentence with its own p
    d = Reason(17, "datum_agrees", Decision.DATUM_DISAGREES, ("plane_form",), "p_form", 0.0012, 0.01)
    assert "datum cloud's form disagrees with the readings' (p = 0.0012)" in verdict_summary(
        _judgement(why + [d], cause=Outcome.NONE, confidence=Confidence.LOW), _tests())


def test_a_judgement_is_typed(hidden):
    from metrology.diagnosis import rules
    from metrology.diagnosis.judge import Judgement
    from metrology.diagnosis.results import Confidence, Outcome

    # the rules give the enums, not strings
    assert rules.confidence_of(True, False, False) is Confidence.HIGH
    assert rules.confidence_of(False, False, False) is Confidence.PARTIAL
    assert rules.confidence_of_nothing(True, True) is Confidence.LOW
    assert rules.confidence_given_datum(Confidence.HIGH, Outcome.NONE, False) is Confidence.LOW
    assert hidden.confidence is Confidence.HIGH and hidden.reasons[-1].outcome is Confidence.HIGH
    v = _judgement((), cause=Outcome.NONE, confidence=Confidence.MODERATE)
    assert v.outcome is Outcome.NONE and _judgement((), cause="drift", confidence=Confidence.HIGH).outcome is Outcome.NAMED
    with pytest.raises(TypeError):  # by keyword only: no positional order to get wrong
        Judgement(Outcome.NONE, [], Confidence.LOW)  # noqa


def test_explain_prints_the_trail_on_the_bundled_hidden_data():
    from typer.testing import CliRunner

    from cli.main import app

    r = CliRunner().invoke(app, ["diagnose", str(H / "export.csv"), "--plane", str(H / "plane.json"),
                                 "--layout", str(H / "layout.toml"), "--explain"])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0].startswith("cause: drift (L3)   confidence: high")
    i = lines.index("why (the rules that made the verdict, in the order they fired)")
    trail = [ln.split(":")[0].strip() for ln in lines[i + 1:i + 6]]
    assert trail == ["rule  2 significant, step 1", "rule  2 significant, step 2",
                     "rule 10 needed_given_others, step 1", "rule 11 explains_sensors, step 1", "rule 16 confidence_of"]
    assert "chosen: drift.L3@temp (p_heldout 0.000315 against level 0.05" in lines[i + 1]
    assert "discrepancy" not in r.output  # the trail, not the full report
