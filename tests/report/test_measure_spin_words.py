"""The measure report's "uncertainty:" line says how U95 took the head's spin where the log has no pose: a
3-sensor log without the pose is judged over every spin, and the line said "+-2 deg" alone (issue 49 item 3,
the walk: 2,000 of 2,000 holes judged over every spin under a line naming the +-2 deg bound)."""

from dataclasses import replace

import numpy as np
import pyarrow.csv as pcsv
import pytest

from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
from metrology.io.layout import layout_to_toml
from metrology.jobs.measure import MeasureOptions, measure_files
from metrology.jobs.measure_report import CadCheck, KnownSurfaces, OffCad
from metrology.report.measure import measure_text
from metrology.sim.forward.log import simulate_log
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.log_write import log_table
from metrology.sim.forward.panels import make_panel


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("spinwords")
    lay = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    lay = lay.with_params(lay.zero, lay.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    (chunk,) = list(simulate_log(LogSpec(true_layout=lay, cell_layout=lay, panel=make_panel("flat")), 3, 60))
    pcsv.write_csv(log_table(chunk), d / "log.csv")
    (d / "L.toml").write_text(layout_to_toml(lay))
    return measure_files(d / "log.csv", d / "L.toml", MeasureOptions(out=d / "h.csv", tolerance_deg=0.5))


def _line(report, on_convention, free):
    off = OffCad(4.0, 300, 0, 2e-4, 5e-4, None)
    cad = CadCheck(0, 0, 0.5, 0.0, 0.0, None, 0.0, 0.0, None)
    known = replace(report, curvature=KnownSurfaces("skin.stl", 77, 0.5, 0.0, 2.0, False, on_convention, free,
                                                     off, cad))
    (line,) = [x for x in measure_text(known).splitlines() if x.startswith("uncertainty:")]
    return line


def test_every_hole_over_every_spin_is_not_called_the_2_deg_bound(report):
    line = _line(report, 0, 2000)
    assert "+-2 deg" not in line and "a U95 over every spin for the 2,000 holes whose spin is not known" in line


def test_both_ways_are_named_and_the_bound_alone_where_no_hole_is_free(report):
    both = _line(report, 255, 1745)
    assert "the head's spin +-2 deg where the log has no pose" in both and "every spin for the 1,745 holes" in both
    assert "every spin" not in _line(report, 30, 0) and "+-2 deg" in _line(report, 30, 0)
