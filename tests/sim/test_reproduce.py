"""The paper's simulation (metrology.sim.reproduce): trials, their summary, determinism."""

import numpy as np
import pytest

from metrology.sim.reproduce import METHOD_ORDER, ReproduceConfig, run_trials, summarize


@pytest.fixture(scope="module")
def small():
    cfg = ReproduceConfig(n_poses=30)
    return cfg, run_trials(cfg, 11, 2)


def test_summary_is_the_mean_and_spread_of_the_trials(small):
    cfg, trials = small
    s = summarize(cfg, trials, 11)
    assert s["trials"] == 2 and list(s["table4"]) == list(METHOD_ORDER)
    for m in METHOD_ORDER:
        dev = [t.deviation_deg[m] for t in trials]
        row = s["table4"][m]
        assert row["max_deg"] == pytest.approx(np.mean([d.max() for d in dev]), rel=1e-12)
        assert row["mean_deg"] == pytest.approx(np.mean([d.mean() for d in dev]), rel=1e-12)
        assert row["std_deg"] == pytest.approx(np.mean([np.std(d, ddof=1) for d in dev]), rel=1e-12)
        assert row["mean_spread_deg"] == pytest.approx(np.std([d.mean() for d in dev], ddof=1), rel=1e-12)
    # the calibration helps: the batch estimator beats the nominal layout on the workpiece
    assert s["table4"]["lsq"]["mean_deg"] < s["table4"]["before"]["mean_deg"]


def test_same_seed_same_trials_and_other_seed_differs(small):
    cfg, trials = small
    again = run_trials(cfg, 11, 2)
    other = run_trials(cfg, 12, 1)
    np.testing.assert_array_equal(again[0].deviation_deg["lsq"], trials[0].deviation_deg["lsq"])
    assert not np.array_equal(other[0].deviation_deg["lsq"], trials[0].deviation_deg["lsq"])


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="layout must be"):
        ReproduceConfig(layout="bogus")
    with pytest.raises(ValueError, match="trials must be"):
        run_trials(ReproduceConfig(n_poses=30), 1, 0)
