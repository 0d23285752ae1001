"""The decision: hidden effects named blind, null data, out-of-catalogue effects, the fixture.

The blind sets here draw their data with :mod:`metrology.sim.synth`, which shares the fit's
own formulas; they run with ``-m slow`` only. The default run's blind checks draw from the
independent forward simulator (``test_blind_forward.py``, ``test_families.py``).
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.io.data import DATA_DIR
from metrology.diagnosis import diagnose
from metrology.sim.synth import SETUP_EFFECTS, HiddenEffect

from .helpers import BELOW_REACH, DETECTABLE, FOLDS, K_SIGMA, draw, run

def _check_named(d, effect, sensor, truth_rec):
    assert d.cause == effect, (d.cause, d.summary)
    if effect not in SETUP_EFFECTS:
        assert d.sensors == [sensor]
    h = d.heldout
    assert h.rms_ratio_concerned > 1.0 and h.p_heldout < 0.05
    params = d.named.params
    if effect == "scale":
        v = params["k"]
        assert abs(v.value - truth_rec["size"]) < K_SIGMA * v.stderr
    elif effect == "drift" and "rate_mm_per_K" in params:
        v = params["rate_mm_per_K"]
        assert abs(v.value - truth_rec["size"]) < K_SIGMA * v.stderr
    elif effect == "nonlinearity":
        for key, true in (("c2_mm", 0.5 * truth_rec["size"]), ("c3_mm", truth_rec["size"])):
            assert abs(params[key].value - true) < K_SIGMA * params[key].stderr, key
    elif effect == "plane_form":
        for key in ("b_ss_mm", "b_st_mm", "b_tt_mm"):
            true = truth_rec["values"][key]
            assert abs(params[key].value - true) < K_SIGMA * params[key].stderr + 0.02 * abs(truth_rec["size"]), key
    elif effect == "pose_error":
        v = params["sigma_mm"]
        assert abs(v.value - truth_rec["size"]) < K_SIGMA * v.stderr
    elif effect == "outliers":
        flagged = d.named.detail["flagged"]
        assert sorted(f["pose"] for f in flagged) == truth_rec["poses"]
        for f in flagged:
            assert abs(abs(f["gross_mm"]) - truth_rec["size"]) < K_SIGMA * f["stderr"] + K_SIGMA * 0.003


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(DETECTABLE))
def test_hidden_effect_named_blind(effect):
    he = draw(effect, 0)
    ds, truth = run([he], 100 + len(effect))
    d = diagnose(ds, folds=FOLDS, sim_reps=1)
    _check_named(d, effect, he.sensor, truth["effects"][0])


#: the blind set's claim: inside the detectable ranges never a wrong catalogued cause, and the
#: right cause, sensor and magnitude in all but a few draws. The ranges' ends are where >= 90 %
#: of 10 trials was measured; inside them the rate is higher (the study: 100 % at most inner
#: sizes). At a true 95 %, 4 or more misses of 25 happen 3 % of the time; at a true 90 %, 24 %
#: (seeded, so a failure means the code changed, not chance). ``BELOW_REACH`` draws are not
#: counted as misses: there only a wrong cause named fails.
BLIND_SEEDS = range(1, 6)
BLIND_MAX_MISSES = 3


@pytest.mark.slow
def test_hidden_effects_blind_set():
    """5 seeded draws per effect: misses are `none` or `unexplained` (at most 3 of 25 inside the
    detectable ranges, any number below reach), and a named catalogued cause is always the right
    one, on the right sensor, of the right size."""
    misses, wrong = [], []
    for effect in sorted(DETECTABLE) + sorted(BELOW_REACH):
        for seed in BLIND_SEEDS:
            he = draw(effect, seed)
            ds, truth = run([he], 1000 * seed + len(effect))
            d = diagnose(ds, folds=FOLDS, sim_reps=1)
            if d.cause in ("none", "unexplained"):
                if effect in DETECTABLE:
                    misses.append((he, d.cause, d.summary))
                else:  # below reach: the summary says what it cannot be told from
                    assert "crosstalk" in d.summary, (he, d.summary)
                continue
            try:
                _check_named(d, effect, he.sensor, truth["effects"][0])
            except AssertionError as exc:
                conf = str(getattr(d.confidence, "value", d.confidence))
                wrong.append(((effect, seed), d.cause, conf, str(exc)))
    # Known wrong, open (found when this test first ran in CI, 2026-11-28; wrong since before the open search,
    # c285ef3): a scale of 0.0136 on L2 (seed 1) is named nonlinearity, `ambiguous` (a d x incidence term and
    # crosstalk tie it; scale is not said as the rival). Listed so that any other wrong name fails, and so that
    # this one, once fixed, fails too (then remove it from the list).
    known = {(("scale", 1), "nonlinearity", "ambiguous")}
    assert {w[:3] for w in wrong} == known, wrong
    assert len(misses) <= BLIND_MAX_MISSES, misses


def test_extended_simulation_predicts_measured_rms():
    """After the extension, the simulator reproduces the measured residual RMS of the sensor."""
    ds, _ = run([HiddenEffect("drift", "L2", 0.008)], 7)
    d = diagnose(ds, folds=FOLDS, sim_reps=2)
    disc = d.discrepancy
    meas, sim_b, sim_e = (np.array(x) for x in (disc.measured_residual_rms_mm, disc.simulated_base_residual_rms_mm,
                                                disc.simulated_extended_residual_rms_mm))
    assert d.cause == "drift" and d.sensors == ["L2"]
    # base simulation misses the excess on L2; the extended one predicts it (RMS of ~80 readings:
    # relative sampling error ~ 1/sqrt(2 * 75) = 8 %; 4 sigma)
    assert meas[1] > 1.3 * sim_b[1]
    assert abs(sim_e[1] / meas[1] - 1) < 4 * 0.08


@pytest.mark.slow
def test_null_gives_none():
    """5 seeded null runs (the forward simulator's nulls are in test_blind_forward, 200 in the
    study). The claim is a false-alarm rate <= 5 % (measured: 2 % with unexplained counted, 0.5 %
    catalogued); at 5 %, two or more alarms in 5 trials happen with probability 2.3 %."""
    causes = [diagnose(run([], 500 + s)[0], folds=FOLDS, sim_reps=1).cause for s in range(5)]
    assert sum(c != "none" for c in causes) <= 1, causes


@pytest.mark.slow
def test_null_false_alarm_rate_below_5_percent():
    causes = [diagnose(run([], 10_000 + s)[0], folds=FOLDS, sim_reps=1).cause for s in range(100)]
    assert sum(c != "none" for c in causes) <= 5, causes


@pytest.mark.parametrize("seed", range(1))
def test_out_of_catalogue_not_named_with_confidence(seed):
    ds, _ = run([HiddenEffect("periodic", "L3", 0.01)], 700 + seed)
    d = diagnose(ds, folds=FOLDS, sim_reps=1)
    assert d.cause == "unexplained" or d.confidence not in ("high", "moderate"), (d.cause, d.summary)


def test_scale_with_little_standoff_spread_is_reported_confounded_or_not_named():
    """A 0.2 % gain error on the typical pose set is mostly hidden in the beam geometry."""
    ds, _ = run([HiddenEffect("scale", "L1", 2e-3)], 31)
    d = diagnose(ds, folds=FOLDS, sim_reps=1)
    cand = {c.label: c for c in d.candidates}
    assert d.cause in ("none", "scale")
    assert cand["scale.L1"].heldout_rms_ratio < 1.2


# ---------------------------------------------------------------------------------------
# the datum cloud: an independent measurement of the datum's form


def test_no_datum_cloud_no_form_section():
    ds, _ = run([], 3, 30)
    assert diagnose(ds, folds=3, sim_reps=1).to_dict()["datum_form"] is None


# ---------------------------------------------------------------------------------------
# the demo data set and the CLI


def test_fixture_hidden_is_diagnosed():

    from metrology.jobs.diagnose import diagnose_files

    here = DATA_DIR / "hidden"
    d = diagnose_files(here / "export.csv", here / "plane.json", here / "layout.toml", folds=FOLDS, sim_reps=1)
    assert d.cause != "none"
    assert d.named is not None and d.heldout.rms_ratio_concerned > 1.0
