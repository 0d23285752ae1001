"""The drift watch on logs of the independent forward simulator (beams cast at the panel, the
cell's own adjustment; metrology/sim/forward/log), measured as `metro measure` measures them."""

import numpy as np
import pytest

from metrology.io.holelog import batch_of
from metrology.measure.chart import ARL_AT_DETECTABLE
from metrology.measure.holes import Settings, measure_batch
from metrology.measure.run import Feed, Watch
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import SensorDrift, SensorShift
from metrology.sim.forward.log_write import log_table
from metrology.sim.forward.panels import make_panel
from tests.measure.helpers import table6_cell_spec


@pytest.fixture(scope="module")
def spec():
    return table6_cell_spec(make_panel("flat"), seed=4)


def _watch(spec, holes, seed):
    watch = Watch(spec.cell_layout.names)
    for c in simulate_cell(spec, seed, 0, holes, chunk_holes=1000):
        t = batch_of(log_table(c), spec.cell_layout.names)
        watch.feed(Feed.of(measure_batch(spec.cell_layout, t, Settings(min_radius_mm=np.inf)), "sim", first_row=int(c.hole[0])))
    watch.finish()
    return watch


def _hole(alarm):
    return int(alarm.hole_id.rsplit("-", 1)[1]) - 1


def test_in_control_log_raises_no_alarm(spec):
    assert _watch(spec, 6000, 1).alarms == []


def test_a_knocked_sensor_is_flagged_within_a_few_holes(spec):
    from dataclasses import replace

    w = _watch(replace(spec, shifts=(SensorShift("L2", -0.015, 2500),)), 4000, 2)  # ~2.5 detectable sizes
    assert len(w.alarms) == 1
    a = w.alarms[0]
    assert 2500 <= _hole(a) <= 2500 + 2 * ARL_AT_DETECTABLE
    assert a.sensor_shift_um["L2"] == pytest.approx(-15.0, abs=2.0)


def test_a_slow_drift_is_flagged(spec):
    from dataclasses import replace

    drift = SensorDrift("L4", 0.012 / 3000, per="hole", start_hole=1500)  # 12 um over 3000 holes
    w = _watch(replace(spec, drifts=(drift,)), 6000, 3)
    assert w.alarms and 1500 < _hole(w.alarms[0]) < 4500


def test_a_transient_run_is_sized_by_its_run_and_named_not_persisted(spec):
    """A sensor knocked by 15 um for 40 holes, then back (two shifts, the forward simulator's): the chart
    alarms on the run; the level after it is the old one. The alarm must give the run it climbed on
    (the residual's mean over the run, ~ the shift's signature times 15 um) and say it did not persist,
    not a size of ~0 um with "recalibrate" (the bug: a false alarm on the default wing log read -0.005 um)."""
    from dataclasses import replace

    knocked = replace(spec, shifts=(SensorShift("L2", -0.015, 2500), SensorShift("L2", 0.015, 2540)))
    w = _watch(knocked, 4000, 2)
    assert len(w.alarms) == 1
    a = w.alarms[0]
    assert 2500 <= _hole(a) < 2540
    steady = _watch(replace(spec, shifts=(SensorShift("L2", -0.015, 2500),)), 4000, 2).alarms[0]
    assert steady.persisted and steady.advice == "recalibrate"
    # the run the chart saw: the steady shift's level change, within its scatter over a few holes
    assert np.sign(a.run_um) == np.sign(steady.size_um) and abs(a.run_um) > 0.5 * abs(steady.size_um)
    assert abs(a.size_um) < 0.2 * abs(steady.size_um)
    assert not a.persisted and a.advice != "recalibrate"
    assert a.to_dict()["persisted"] is False and a.to_dict()["run_um"] == a.run_um


def test_a_persistent_shift_is_sized_by_the_level_change(spec):
    """A steady knock: the new level minus the old gives the shift at the sensor (15 um at L2), and
    the run the chart climbed on has the same sign."""
    from dataclasses import replace

    a = _watch(replace(spec, shifts=(SensorShift("L2", 0.015, 2500),)), 4000, 3).alarms[0]
    assert a.persisted
    assert a.sensor_shift_um["L2"] == pytest.approx(15.0, abs=2.0)
    assert np.sign(a.run_um) == np.sign(a.size_um)
