"""Forward selection of several causes (issue 15): members re-chosen given the later causes, the
keep rule of a cause that acts on every sensor, gross readings under a rigid pose error.

The data come from the independent forward simulator (:mod:`metrology.sim.forward`). The slow
cases are pairs of the blind study (``benchmarks/study_blind.py``, their seed entropy) that the
selection missed before these changes.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

from metrology.core.effects import Outliers
from metrology.diagnosis.stats import NoiseTests, SensorTests
from metrology.diagnosis.thresholds import THRESHOLDS
from metrology.sim.forward import draw_case, draw_pair, write_case


def _dataset(case, tmp_path):
    from metrology.calibration.sanity import load_checked

    paths = write_case(case, tmp_path)
    return load_checked(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"], "wxyz", "mm", None, None)


def _diagnose(case, tmp_path):
    from metrology.jobs.diagnose import diagnose_files

    paths = write_case(case, tmp_path)
    return diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"]).to_dict()


def test_pruning_keeps_families_whole_and_waits_for_a_cause_on_its_own_sensors():
    """Which candidates a later step rescores (select._seen_after, select._prune), on scripted
    step scores: a family stays whole where one member showed something; a set-up cause
    defers the pruning; a set-up cause after a pruning undoes it; a sensor where a cause was
    found later gets its candidates back; gross readings are always rescored."""
    from metrology.core.effects import Drift, PlaneForm, Scale
    from metrology.diagnosis.select import _prune, _seen_after

    names = ("L1", "L2", "L3", "L4")
    drift = {(i, v, o): Drift((i,), names=names, variable=v, order=o) for i in range(4)
             for v, o in (("time", 1), ("time", 3), ("temp", 1))}
    scale = {i: Scale((i,), names=names) for i in range(4)}
    form = PlaneForm((), names=names)
    gross = Outliers((3,), names=names, flags=np.zeros((5, 4), bool))
    remaining = list(drift.values()) + list(scale.values()) + [form, gross]

    def scored(p):  # in-sample p by label; the rest show nothing
        return [SimpleNamespace(component=c, label=c.label, p_insample=p.get(c.label, 0.9)) for c in remaining]

    def labels(cs):
        return {c.label for c in cs}

    # a drift on L2 chosen at step 1; of L1's drift only the line in time showed (p 0.1)
    step1 = scored({"drift.L1@time": 0.1, "drift.L2@temp": 1e-9})
    seen = _seen_after(drift[1, "temp", 1], step1, None)
    left = [c for c in remaining if not (c.sensors == (1,) and c.name == "drift")]  # its family leaves
    kept = labels(_prune(left, (drift[1, "temp", 1],), seen))
    assert {"drift.L1@time", "drift.L1@time3", "drift.L1@temp"} <= kept  # L1's drift family whole
    assert "scale.L2" in kept  # shares L2 with the cause found
    assert {form.label, gross.label} <= kept
    assert not kept & {"scale.L1", "scale.L3", "scale.L4", "drift.L3@time", "drift.L4@temp"}
    # a cause found later on L3 brings back the candidates of L3 that were pruned
    kept3 = labels(_prune(left, (drift[1, "temp", 1], scale[2]), seen))
    assert "drift.L3@time3" in kept3 and "drift.L4@time" not in kept3
    # a set-up cause first: nothing is pruned, whatever the scores showed under it
    assert _seen_after(form, scored({form.label: 1e-30}), None) is None
    assert labels(_prune(remaining, (form,), None)) == labels(remaining)
    # a set-up cause after a pruning undoes it: the next step rescores every family
    assert _seen_after(form, scored({form.label: 1e-30}), seen) is None
    # once taken, the families seen are kept (a later step's scores do not replace them)
    assert _seen_after(scale[2], scored({}), seen) is seen


def test_gross_reading_under_a_rigid_pose_error_is_found_and_placed(tmp_path):
    """A rigid pose error spreads a gross reading over its pose; the reading is still found, on
    its own sensor (a 4-sensor head, an orientation-only pose error, 3 gross readings of which
    the first flagging, without the pose error, finds 2)."""
    from metrology.core.effects import Outliers, PoseError
    from metrology.diagnosis.candidates import flag_outliers
    from metrology.diagnosis.decide import base_analysis
    from metrology.diagnosis.fit import FitData, fit_any
    from metrology.diagnosis.select import flag_given_rigid

    case = draw_pair(np.random.default_rng([1, 3, 7, 15]), "pose_error", "outliers")
    ds = _dataset(case, tmp_path)
    names = ds.layout.names
    truth = {(p, names.index(s)) for p, s, _ in next(e for e in case.effects if e.family == "outliers").shape["cells"]}
    b = base_analysis(ds, 5)
    flags, _ = flag_outliers(ds.layout, ds.obs, b.cov, b.sigma, b.theta0)
    first = {tuple(x) for x in np.argwhere(flags).tolist()}
    assert first < truth  # the first flagging misses one (else this case tests nothing)
    out = Outliers(tuple(sorted({i for _, i in first})), names=names, flags=flags)
    f0 = fit_any(FitData(ds.layout, ds.obs, b.cov, b.sigma), (out,), b.theta0)
    rigid = PoseError((), names=names, n_poses=ds.obs.n_poses, tilts=True)
    f = fit_any(FitData(ds.layout, ds.obs, b.cov, b.sigma), (out, rigid), f0.theta)
    new, p = flag_given_rigid(f, b.cov, b.sigma, flags)
    assert {tuple(x) for x in np.argwhere(new).tolist()} == truth
    assert p < THRESHOLDS["alpha_outlier"]


def _tests(p_sensor, n):
    """A noise battery whose only failing tests are the per-sensor ones given in ``p_sensor``."""
    pv = tuple((p_sensor.get(i, 0.5), {i}) for i in range(n)) + tuple((0.5, {i}) for i in range(n))
    p_all = min(1.0, min(p for p, _ in pv) * len(pv))
    per = {f"L{i + 1}": SensorTests(float("nan"), 1, float("nan"), p_sensor.get(i, 0.5), 0.5, None) for i in range(n)}
    return NoiseTests(per, {}, len(pv), p_all, p_all >= THRESHOLDS["alpha_battery"], pv)


def _chosen(*sensors):
    return [SimpleNamespace(component=SimpleNamespace(sensors=s, drops_readings=False), label=f"c{k}")
            for k, s in enumerate(sensors)]


def test_an_all_sensor_cause_is_judged_beside_structure_that_belongs_elsewhere():
    from metrology.diagnosis.judge import _judged_sensors

    n = 3
    bad = {2: 1e-8}  # structure left on sensor 2 only
    # a form (every sensor) and a drift on sensor 2 that its member follows only in part
    form_drift = _chosen((), (2,))
    needed = [(500.0, 1e-6), (40.0, 1e-3)]
    assert _judged_sensors(form_drift, _tests(bad, n), needed, n, []) == [[0, 1], []]
    # not needed given the others: not named
    assert _judged_sensors(form_drift, _tests(bad, n), [(3.0, 0.3), (40.0, 1e-3)], n, []) == [[], []]
    # structure on one sensor and no other cause there: named beside it
    assert _judged_sensors(_chosen(()), _tests(bad, n), needed[:1], n, []) == [[0, 1]]
    # structure on two sensors that no other cause explains: the cause itself is in doubt
    assert _judged_sensors(_chosen(()), _tests({1: 1e-8, 2: 1e-8}, n), needed[:1], n, []) == [[]]
    # a per-sensor cause is judged on its own sensors as before, rule 11 said in the trail
    why = []
    assert _judged_sensors(_chosen((1,)), _tests(bad, n), needed[:1], n, why) == [[1]]
    assert [(r.rule, r.decided, r.concerns) for r in why] == [(11, "explains its sensors", ("c0", "L2"))]
    assert _judged_sensors(_chosen((2,)), _tests(bad, n), needed[:1], n, []) == [[]]


def test_a_cause_is_named_only_while_needed_and_a_sole_cause_too():
    """Each chosen cause must be needed given the others (held-out p below alpha_heldout split
    over the causes); a sole cause is tested against the base model the same way, and gross
    readings, which predict nothing held out, are exempt."""
    from metrology.diagnosis.select import needed

    a = THRESHOLDS["alpha_heldout"]
    one = _chosen(())
    assert needed(one, [(17.2, 0.056)]) == [False]  # seed-104 null 34: a datum "form", refitted
    assert needed(one, [(17.2, 0.029)]) == [True]
    two = _chosen((0,), (1,))
    assert needed(two, [(40.0, 0.6 * a), (40.0, 0.4 * a)]) == [False, True]  # Bonferroni over 2
    flags = np.zeros((4, 3), bool)
    flags[2, 1] = True
    gross = [SimpleNamespace(component=Outliers((1,), [0.2], names=("L1", "L2", "L3"), flags=flags))]
    assert needed(gross, [(0.0, 1.0)]) == [True]


def test_a_sole_cause_turned_down_is_not_named_and_its_test_is_said(tmp_path, monkeypatch):
    """The wiring of the rule above: a clear drift (4 sensors, 40 poses) whose drop-one test is
    made to fail is not named, the steps table marks its step not named, and the summary gives
    that test's p (unpatched, it is named: test_clear_case_names_cause_and_sensor)."""
    import metrology.diagnosis.judge as judge

    case = draw_case(np.random.default_rng([11]), "drift", n_sensors=4, n_poses=40, size=0.05)
    drop_one = judge.drop_one_gains
    monkeypatch.setattr(judge, "drop_one_gains", lambda *a: [(g, 0.2) for g, _ in drop_one(*a)])
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "unexplained" and not res["causes"], res["summary"]
    assert res["confidence"] == "low"
    assert res["steps"][1]["added"].startswith("drift.") and res["steps"][1]["named"] is False
    assert "not needed against the base model" in res["summary"] and "p = 0.2)" in res["summary"]


def test_confidence_high_needs_strong_held_out_evidence_for_every_cause():
    """A cause named on a held-out p at or above alpha_high (0.01) is weakly supported: a null
    named ``incidence`` at p = 0.026 (seed 106) is one. Gross readings and a random pose error
    (no held-out p) are exempt."""
    from metrology.diagnosis.select import weakly_supported

    a = THRESHOLDS["alpha_high"]

    from metrology.diagnosis.results import Cause

    def cause(label, p):
        return Cause(label, label.split(".")[0].split("@")[0], [], None, 1.0, p, 1e-9, 1)

    assert weakly_supported([cause("incidence.L3@4", 0.026)]) == ["incidence.L3@4"]
    assert weakly_supported([cause("drift.L2@temp", 0.9 * a), cause("scale.L1", a)]) == ["scale.L1"]
    assert weakly_supported([cause("outliers.L1", 0.049), cause("pose_error@random", None),
                             cause("drift.L1@time", 1e-9)]) == []


def test_a_cause_on_weak_evidence_is_named_with_moderate_confidence(tmp_path, monkeypatch):
    """The wiring: the clear drift above (named ``high`` unpatched, at p = 0.0002 against the base
    model) with its drop-one p made 0.02 is still named, ``confidence: moderate``, and the
    summary says why."""
    import metrology.diagnosis.judge as judge

    case = draw_case(np.random.default_rng([11]), "drift", n_sensors=4, n_poses=40, size=0.05)
    drop_one = judge.drop_one_gains
    monkeypatch.setattr(judge, "drop_one_gains", lambda *a: [(g, 0.02) for g, _ in drop_one(*a)])
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "drift" and res["confidence"] == "moderate", res["summary"]
    assert res["summary"].endswith("; confidence moderate: weak held-out evidence for " + res["causes"][0]["label"]
                                   + " (p = 0.02), not below 0.01"), res["summary"]


def test_rigid_member_holds_the_geometry_the_offset_member_finds(tmp_path):
    """A 0.066 mm rigid pose error at 3.1 um noise (4 sensors, 138 poses: the blind study's seed-70
    pose-error draw 9). The calibration without a pose error takes up part of its common mode:
    held there, the rigid member left 4-5 um RMS, failed the noise battery and predicted
    held-out poses worse than the offset alone, and the case came out ``unexplained``. Held
    where the offset member puts the geometry, it leaves the noise and predicts them better."""
    from metrology.core.effects import PoseError
    from metrology.diagnosis.candidates import Scoring, candidates_for, flag_outliers
    from metrology.diagnosis.decide import base_analysis
    from metrology.diagnosis.members import Reference, _consistent, p_better, score_step

    case = draw_case(np.random.default_rng([70, 1, 0, 9]), "pose_error")
    assert case.nominal.n == 4 and case.effects[0].shape["angle_rad"] > 0
    ds = _dataset(case, tmp_path)
    b = base_analysis(ds, 5)
    flags, p_out = flag_outliers(ds.layout, ds.obs, b.cov, b.sigma, b.theta0)
    n_cand = len(candidates_for(ds.layout, b.cov, flags))
    off, rigid = score_step(Scoring(ds, b, flags, p_out, 5, n_cand), Reference((), b.fit, b.heldout),
                            PoseError.candidates_for_setup(ds.layout.names, b.cov))
    assert (off.label, rigid.label) == ("pose_error", "pose_error@rigid")
    assert off.significant and not _consistent(ds, b, off)  # the orientation part stays in the offset's residuals
    assert rigid.significant and _consistent(ds, b, rigid)
    assert p_better(rigid, off) < THRESHOLDS["alpha_order"]


def test_a_per_pose_cause_gives_way_to_fixed_causes_that_predict_as_well():
    from metrology.diagnosis.heldout import HeldOut
    from metrology.diagnosis.select import Step, _fixed_explains

    rng = np.random.default_rng(0)
    b = SimpleNamespace(sigma=np.full(4, 0.005))

    def steps(residual, label, flags=None):
        comp = SimpleNamespace(sensors=()) if flags is None else Outliers((0,), names=("a", "b", "c", "d"), flags=flags)
        chosen = SimpleNamespace(component=comp, label=label, fit=SimpleNamespace(residual=residual),
                                 heldout=HeldOut(residual, np.zeros(len(residual))))
        return [Step(chosen, (), None), Step(None, (), None)]

    r = np.repeat(rng.normal(0, 0.005, (30, 4)), 2, axis=0)  # poses in identical pairs
    per_pose = steps(r, "pose_error@rigid")
    # as well held out: half the poses predicted 20 % better, their twins 20 % worse
    as_well = r * np.sqrt(np.where(np.arange(60) % 2, 0.8, 1.2))[:, None]
    assert _fixed_explains(b, per_pose, steps(as_well, "drift.L1@temp"))
    assert not _fixed_explains(b, per_pose, steps(1.3 * r, "drift.L1@temp"))  # worse: the per-pose cause stays
    assert not _fixed_explains(b, per_pose, [Step(None, (), None)])  # no fixed cause at all
    # the fixed causes all among the per-pose selection's: it was added to them on its own test
    assert not _fixed_explains(b, per_pose, steps(as_well, "pose_error@rigid"))
    # a pose with a gross reading is left out whole: unflagged in the per-pose model, it spreads
    # over the pose's other held-out readings (here 0.1 mm), which would make the fixed causes,
    # 1.3 times worse everywhere else, look as good
    spread, gross, flags = r.copy(), 1.3 * r, np.zeros(r.shape, bool)
    spread[::2, 0] += 0.5
    spread[::2, 1:] += 0.1
    gross[::2, 0] += 0.5
    flags[::2, 0] = True
    assert not _fixed_explains(b, steps(spread, "pose_error@rigid"), steps(gross, "drift.L1@temp", flags))
    assert not _fixed_explains(b, steps(spread, "pose_error@rigid"), steps(gross, "drift.L1@temp"), flags)


@pytest.mark.slow  # ~10 s
def test_two_drifts_are_not_taken_for_a_pose_error(tmp_path):
    """Two sensors of a 4-sensor head drift each on its own (the blind study's seed-100 pair 6:
    0.086 mm on L1, 0.094 mm on L2, 79 poses, 5.3 um noise). An offset and two tilts a pose take
    three quarters of each drift and predict held-out poses better than either drift alone: the
    rigid pose error took the first step and was named beside the drift on L2, a wrong cause.
    The two drifts, two values, explain as much."""
    case = draw_pair(np.random.default_rng([100, 3, 6, 6]), "drift", "drift")
    assert case.nominal.n == 4
    res = _diagnose(case, tmp_path)
    named = {(c["cause"], tuple(c["sensors"])) for c in res["causes"]}
    assert named == {("drift", tuple(e.sensors)) for e in case.effects}, res["summary"]
    assert all(s["model"] != "pose_error" and "pose_error" not in s["model"] for s in res["steps"])


@pytest.mark.slow  # ~15 s each
def test_rigid_member_chosen_once_the_drift_is_modelled(tmp_path):
    """A 4-sensor pose error with an orientation part and a drift: the offset-only member wins
    step 1 while the drift is unmodelled; re-chosen given the drift, the rigid member is named."""
    case = draw_pair(np.random.default_rng([2, 3, 2, 2]), "pose_error", "drift")
    assert case.effects[0].shape["angle_rad"] > 0 and case.nominal.n == 4
    res = _diagnose(case, tmp_path)
    labels = {c["label"] for c in res["causes"]}
    drift = next(e for e in case.effects if e.family == "drift")
    assert "pose_error@rigid" in labels, res["summary"]
    assert any(c["cause"] == "drift" and c["sensors"] == list(drift.sensors) for c in res["causes"]), res["summary"]


@pytest.mark.slow
def test_form_and_a_warm_up_drift_are_named_and_nothing_else(tmp_path):
    """A datum form and a small warm-up drift on one sensor (3 sensors, 51 poses). Under the form,
    only the drift's line in time showed anything at step 1 (in-sample p 0.2); once the line
    alone was left in the pool, the structure it left on its sensor was taken for a random
    tracker pose error, a third cause. The step after a set-up cause scores every family (its
    members ruled on by test_pruning_keeps_families_whole_and_waits_for_a_cause_on_its_own_sensors):
    the thermal member is chosen, both causes are named, and nothing else."""
    case = draw_pair(np.random.default_rng([2, 3, 4, 12]), "plane_form", "drift")
    res = _diagnose(case, tmp_path)
    drift = next(e for e in case.effects if e.family == "drift")
    assert res["cause"] == "plane_form", res["summary"]
    named = {(c["cause"], tuple(c["sensors"])) for c in res["causes"]}
    assert named == {("plane_form", ()), ("drift", tuple(drift.sensors))}, res["summary"]
    assert res["confidence"] == "high"


@pytest.mark.slow
def test_a_drift_hidden_under_a_datum_form_at_step_one_is_scored_again(tmp_path):
    """The blind study's seed-103 pair 36: a 0.42 mm datum form and a 0.069 mm drift on L1 (3
    sensors, 52 poses). Under the form every drift member of L1 had in-sample p 0.3-0.9 at step
    1: the form inflated every sensor's scatter. Pruned then, the drift was never scored given
    the form, and the verdict was the form with structure left on L1. A set-up cause defers the
    pruning to the next step: both are named."""
    case = draw_pair(np.random.default_rng([103, 3, 4, 36]), "plane_form", "drift")
    res = _diagnose(case, tmp_path)
    drift = next(e for e in case.effects if e.family == "drift")
    named = {(c["cause"], tuple(c["sensors"])) for c in res["causes"]}
    assert named == {("plane_form", ()), ("drift", tuple(drift.sensors))}, res["summary"]
    assert res["confidence"] == "high"


@pytest.mark.slow
def test_rigid_pose_error_and_gross_readings_both_named(tmp_path):
    case = draw_pair(np.random.default_rng([1, 3, 7, 15]), "pose_error", "outliers")
    res = _diagnose(case, tmp_path)
    gross = next(e for e in case.effects if e.family == "outliers")
    assert {c["cause"] for c in res["causes"]} == {"pose_error", "outliers"}, res["summary"]
    assert next(c for c in res["causes"] if c["cause"] == "outliers")["sensors"] == list(gross.sensors)


@pytest.mark.slow
def test_drop_one_holds_the_geometry_where_the_selection_held_it(tmp_path):
    """The blind study's seed-105 pair 39: a rigid pose error (0.038 mm and 0.048 deg a pose) and
    six gross readings on L1, L2 and L4 (4 sensors, 52 poses). Step 3 added a nonlinearity on L1
    at held-out p = 0.046. The drop-one test held the geometry of the model without it at the
    base calibration, which the pose error biases, and found the curve "needed" at p = 1e-6; held
    where the selection held it, it is not (p = 0.046 against 0.05/3), and only the two causes
    are named."""
    case = draw_pair(np.random.default_rng([105, 3, 7, 39]), "pose_error", "outliers")
    res = _diagnose(case, tmp_path)
    gross = next(e for e in case.effects if e.family == "outliers")
    named = {(c["cause"], tuple(c["sensors"])) for c in res["causes"]}
    assert named == {("pose_error", ()), ("outliers", tuple(gross.sensors))}, res["summary"]
    assert [st["added"] for st in res["steps"] if st.get("named") is False] == ["nonlinearity.L1"]


@pytest.mark.slow
def test_a_sole_cause_not_needed_against_the_base_model_is_not_named(tmp_path):
    """The blind study's seed-104 null 34 (4 sensors, 90 poses, no effect). A cubic datum form
    was selected beyond the plane's tilt (held-out p = 0.032) and named alone, `confidence:
    high`; against the base model it gives p = 0.056. A sole cause now passes the
    test that each of several causes passes: nothing is named, and the candidate is said."""
    case = draw_case(np.random.default_rng([104, 0, 0, 34]), "none")
    assert not case.effects
    res = _diagnose(case, tmp_path)
    assert res["cause"] == "none" and not res["causes"], res["summary"]
    assert res["confidence"] == "low"
    assert "plane_form@cubic was selected (held-out p = 0.032" in res["summary"]
    # the figures move with the base fit (17.2, p = 0.056 when this was written; 16.4, p = 0.066 since): what is
    # tested is the rule, a p above the held-out level against the base model
    m = re.search(r"not needed against the base model \(held-out chi-square gain ([-0-9.e+]+), p = ([0-9.e-]+)\)",
                  res["summary"])
    assert m is not None, res["summary"]
    assert 0.05 < float(m.group(2)) < 0.2, res["summary"]
    assert res["steps"][-1]["added"] == "plane_form@cubic" and res["steps"][-1]["named"] is False
