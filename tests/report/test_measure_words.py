"""The measure report reads MeasureReport's typed fields as attributes (metrology.jobs.measure_report,
metrology.report.measure): the curvature's account, the files and the chart's settings."""

from dataclasses import replace

import numpy as np
import pyarrow.csv as pcsv
import pytest

from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
from metrology.io.layout import layout_to_toml
from metrology.jobs.measure import MeasureOptions, measure_files
from metrology.jobs.measure_report import CadCheck, KnownSurfaces, OffCad, RadiusBound, Sources
from metrology.report.measure import measure_text
from metrology.sim.forward.log import simulate_log
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.log_write import log_table
from metrology.sim.forward.panels import make_panel


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("words")
    lay = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    lay = lay.with_params(lay.zero, lay.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    (chunk,) = list(simulate_log(LogSpec(true_layout=lay, cell_layout=lay, panel=make_panel("flat")), 3, 400))
    pcsv.write_csv(log_table(chunk), d / "log.csv")
    (d / "L.toml").write_text(layout_to_toml(lay))
    return measure_files(d / "log.csv", d / "L.toml", MeasureOptions(out=d / "h.csv", tolerance_deg=0.5))


def test_an_assumed_radius_is_named_in_the_verdict_text_and_json(report):
    assert report.curvature == RadiusBound(500.0)
    assert isinstance(report.sources, Sources) and report.sources.out.endswith("h.csv")
    text = measure_text(report)
    assert "curvature ASSUMED (no --panel/--points): every panel's radius >= 500 mm" in text
    assert f"holes of {report.sources.log} " in text and f"(k {report.chart.k}, h {report.chart.h}," in text
    d = report.to_dict()
    assert list(d["sources"]) == ["log", "layout", "out"] and d["curvature"]["assumed"] is True
    assert d["drift"]["chart"]["by_panel"] is False and d["drift"]["chart"]["k"] == report.chart.k


def test_a_stated_radius_and_known_surfaces_are_read_as_attributes(report):
    stated = replace(report, curvature=RadiusBound(800.0, "cell.toml"))
    assert "curvature from bound: the cell's panel radius 800 mm stated in cell.toml" in measure_text(stated)
    assert stated.to_dict()["curvature"] == {"assumed": False, "radius_mm": 800.0, "source": (
        "bound: the cell's panel radius 800 mm stated in cell.toml [panel] radius_mm"), "one_sensor_offset_holes": 0}
    off = OffCad(4.0, 300, 7, 2e-4, 5e-4, "H12")
    cad = CadCheck(0, 0, 0.5, 0.0, 0.0, None, 0.0, 0.0, None)
    known = replace(report, curvature=KnownSurfaces("wing.stl", 400, 0.2, 0.05, 2.0, False, 30, 2, off, cad))
    text = measure_text(known)
    assert "each hole's curvature from wing.stl" in text and "the head's spin +-2 deg" in text
    checks = {c.name.split(":")[0]: c.value for c in known.verdict.checks}
    assert checks["panel off its CAD"] == 7 and checks["head's spin not known"] == 2
    assert "panel against its CAD (the log's commanded pose)" not in checks  # nothing checked: not shown
    d = known.to_dict()["curvature"]
    assert d["off_cad_max_hole"] == "H12" and d["spin_on_convention_holes"] == 30


# The "uncertainty:" line says how U95 took the head's spin where the log has no pose: a 3-sensor log without the
# pose is judged over every spin, and the line said "+-2 deg" alone (issue 49 item 3, the walk: 2,000 of 2,000
# holes judged over every spin under a line naming the +-2 deg bound).
def _spin_line(report, on_convention, free):
    off = OffCad(4.0, 300, 0, 2e-4, 5e-4, None)
    cad = CadCheck(0, 0, 0.5, 0.0, 0.0, None, 0.0, 0.0, None)
    known = replace(report, curvature=KnownSurfaces("skin.stl", 77, 0.5, 0.0, 2.0, False, on_convention, free,
                                                     off, cad))
    (line,) = [x for x in measure_text(known).splitlines() if x.startswith("uncertainty:")]
    return line


def test_every_hole_over_every_spin_is_not_called_the_2_deg_bound(report):
    line = _spin_line(report, 0, 2000)
    assert "+-2 deg" not in line and "a U95 over every spin for the 2,000 holes whose spin is not known" in line


def test_both_ways_are_named_and_the_bound_alone_where_no_hole_is_free(report):
    both = _spin_line(report, 255, 1745)
    assert "the head's spin +-2 deg where the log has no pose" in both and "every spin for the 1,745 holes" in both
    assert "every spin" not in _spin_line(report, 30, 0) and "+-2 deg" in _spin_line(report, 30, 0)
