"""Rule 1's tails: readings flagged on a sensor whose other readings are heavier-tailed than a normal,
each within reach of the threshold, are the tails of its noise (rule 21 judges them), not gross
readings (issue 54: heavy-tailed noise named ``outliers`` high)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from metrology.diagnosis import rules
from metrology.diagnosis.candidates import without_tails
from metrology.diagnosis.results import Outcome
from metrology.jobs.diagnose import diagnose_files
from metrology.sim.forward import draw_outside, write_case


def test_the_rule_needs_both_a_heavy_rest_and_flags_within_reach():
    t = 4.0
    assert rules.tails_not_gross(0.01, 6.0, t)
    assert not rules.tails_not_gross(0.2, 6.0, t)  # the rest is normal: the flags are gross
    assert not rules.tails_not_gross(0.01, rules.TAIL_REACH * t + 0.1, t)  # far beyond any noise's edge
    assert rules.THRESHOLDS["tail_reach"] == rules.TAIL_REACH


def _flag(z):
    m = int(np.isfinite(z).sum())
    t = float(stats.norm.isf(rules.gross_level(m)))
    return np.isfinite(z) & (np.abs(z) > t), t


def test_gross_readings_on_normal_noise_stay_flagged_and_a_heavy_tail_does_not():
    rng = np.random.default_rng(54)
    p = 120
    z = rng.normal(size=(p, 2))
    z[[10, 70], 0] = [40.0, -25.0]  # gross readings: lost, far beyond the noise
    broad = rng.random(p) < 0.12  # a contaminated normal: 12 % of the readings 3.5 times broader
    z[:, 1] = np.where(broad, 3.5 * rng.normal(size=p), rng.normal(size=p))
    z[5, 1] = 6.0  # the broad part's edge, past the threshold
    flags, t = _flag(z)
    assert flags[:, 1].any() and flags[10, 0] and flags[70, 0]
    kept = without_tails(flags, z, t)
    assert kept[10, 0] and kept[70, 0] and kept[:, 0].sum() == flags[:, 0].sum()
    assert not kept[:, 1].any()


@pytest.mark.slow
def test_heavy_tailed_noise_is_not_named_outliers(tmp_path):
    """A heavy-tailed sensor (drawn where the flags caught its three largest readings, 5-7 sigmas)."""
    case = draw_outside(np.random.default_rng([5481, 1, 6, 2]), "heavy_tails")
    paths = write_case(case, tmp_path)
    d = diagnose_files(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
    assert d.cause == Outcome.UNEXPLAINED and "outliers" not in {c.cause for c in d.causes}, d.summary
    assert d.empirical.terms and d.empirical.terms[0].key == "tails"
    assert d.empirical.terms[0].sensor == case.effects[0].sensors[0]
