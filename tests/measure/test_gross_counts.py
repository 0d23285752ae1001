"""The summary's own counts of the holes two rules judged with a wider U95, typed through HoleBatch, FleetSummary
and MeasureReport to the report's check lines and ``--json``: rule 2b's (one sensor's offset within the radius
bound, no panel) and the spin alias rule's (judged over every spin, the convention not stated). Logs from the
independent forward simulator."""

from dataclasses import replace

import numpy as np
import pyarrow.csv as pcsv
import pytest

from metrology.io.holelog import batch_of
from metrology.io.layout import layout_to_toml
from metrology.measure.holes import Settings, measure_batch
from metrology.measure.reasons import EDGE_TEXT
from metrology.measure.summary import FleetSummary
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import SensorShift
from metrology.sim.forward.log_write import log_table
from metrology.sim.forward.panels import make_panel
from tests.measure.helpers import table6_cell_spec

TOL = np.radians(0.5)
#: the check line's words (metrology.jobs.measure_report)
ONE_SENSOR = "one sensor's offset (rule 2b)"
ALIAS = "head's spin alias (the convention not stated)"


def _log(shifts=(), holes=100, seed=3):
    spec = table6_cell_spec(make_panel("flat"), shifts=shifts)
    (chunk,) = list(simulate_cell(spec, seed, 0, holes, chunk_holes=holes))
    return spec.cell_layout, log_table(chunk)


def _edge_text(batch):
    return np.array([EDGE_TEXT in (r or "") for r in batch.columns.column("reason").to_pylist()])


@pytest.fixture(scope="module")
def offset():
    """1 mm under L2's spot, alike before and after: every hole's misfit within R 500's bound, every hole rule 2b's."""
    return _log((SensorShift("L2", 1.0, 0),))


def test_rule_2b_holes_are_counted_by_the_summary_and_its_merge(offset):
    layout, log = offset
    b = measure_batch(layout, batch_of(log, layout.names), Settings(tolerance=TOL))
    shown = _edge_text(b)
    assert shown.sum() > 90  # the case is there: said in the reason of every failing or undecided hole
    assert np.array_equal(b.one_sensor, shown)  # none conforms or is not measured here: the text shows them all
    whole = FleetSummary(0.5)
    whole.add(b)
    assert whole.one_sensor == shown.sum() and whole.spin_alias == 0
    halves = FleetSummary(0.5)
    for part in (log.slice(0, 37), log.slice(37)):
        other = FleetSummary(0.5)
        other.add(measure_batch(layout, batch_of(part, layout.names), Settings(tolerance=TOL)))
        halves.merge(other)
    assert halves.one_sensor == whole.one_sensor
    clean_layout, clean = _log(holes=200, seed=4)
    s = FleetSummary(0.5)
    s.add(measure_batch(clean_layout, batch_of(clean, clean_layout.names), Settings(tolerance=TOL)))
    assert s.one_sensor == 0


@pytest.fixture(scope="module")
def offset_report(offset, tmp_path_factory):
    from metrology.jobs.measure import MeasureOptions, measure_files

    layout, log = offset
    d = tmp_path_factory.mktemp("counts")
    pcsv.write_csv(log, d / "log.csv")
    (d / "L.toml").write_text(layout_to_toml(layout))
    return measure_files(d / "log.csv", d / "L.toml", MeasureOptions(out=d / "h.csv", tolerance_deg=0.5))


def test_the_report_and_json_show_rule_2b_count(offset_report):
    from metrology.report.measure import measure_text

    n = offset_report.result.summary.one_sensor
    assert n > 90
    (check,) = [c for c in offset_report.verdict.checks if c.name.startswith(ONE_SENSOR)]
    assert check.value == n and not check.gate
    d = offset_report.to_dict()
    assert d["curvature"]["one_sensor_offset_holes"] == n
    assert any(c["value"] == n and c["name"].startswith(ONE_SENSOR) for c in d["verdict"]["checks"])
    assert ONE_SENSOR in measure_text(offset_report)
    # where rule 2b cannot apply (no redundant reading, or no radius bound), no line
    three = replace(offset_report, layout_names=("L1", "L2", "L3"))
    assert not any(c.name.startswith(ONE_SENSOR) for c in three.verdict.checks)
    flat = replace(offset_report, curvature=replace(offset_report.curvature, radius_mm=float("inf")))
    assert not any(c.name.startswith(ONE_SENSOR) for c in flat.verdict.checks)


def _alias_said(b):
    return np.array(["cannot tell it from a spin of" in (r or "") for r in b.columns.column("reason").to_pylist()])


def test_the_alias_rule_holes_are_counted_as_their_reason_names_them():
    """Counted whichever readings the alias judged over every spin: the before-readings' where the after-readings
    judged keep the spin from before (on the convention: the bundled wing without its pose, 1641 of 2000 holes),
    and not the holes the misfit's test sent to every spin."""
    import pyarrow as pa

    from tests.measure.test_spin import _inputs
    from tests.measure.test_spin_alias import _free_spin

    lay, log, settings, ch = _inputs(4, 2.0, holes=60)  # a barrel R 600, a spin within +-2 deg, nothing stated
    for j, name in enumerate(lay.names):
        log = log.append_column(f"d_{name}_after", pa.array(ch.d_after[:, j]))
    b = measure_batch(lay, log, settings)
    said = _alias_said(b)
    assert said.sum() >= 10 and (said & b.on_convention).sum() >= 10  # the case is there: judged after, on it
    assert np.array_equal(b.spin_alias, said)
    s = FleetSummary(0.5)
    s.add(b)
    assert s.spin_alias == said.sum() and s.one_sensor == 0 and s.spin_free == 0
    free, _, _ = _free_spin(holes=60)  # a spin anywhere: most holes sent to every spin by the misfit's test
    said = _alias_said(free)
    assert said.sum() >= 3 and (free.spin_free & ~said).sum() >= 3
    assert np.array_equal(free.spin_alias, said)


def test_the_alias_count_has_its_line_where_the_convention_is_not_stated_and_its_json_field():
    from metrology.jobs.measure_report import CadCheck, KnownSurfaces, OffCad

    off, cad = OffCad(4.0, 0, 0, 0.0, 0.0, None), CadCheck(0, 0, 0.5, 0.0, 0.0, None, 0.0, 0.0, None)
    cv = KnownSurfaces("skin.stl", 60, 0.5, 0.0, 2.0, False, 60, 0, off, cad, 0, 41)
    assert _checks_of(cv)[ALIAS] == 41
    assert ALIAS not in _checks_of(replace(cv, spin_stated=True))
    assert ALIAS not in _checks_of(cv, ("L1", "L2", "L3"))  # no redundant reading: no alias to tell
    assert cv.to_dict()["spin_alias_holes"] == 41


def _checks_of(cv, names=("L1", "L2", "L3", "L4")):
    """The verdict's checks by name (before any ':') of a report whose curvature is ``cv`` (the rest made up)."""
    from types import SimpleNamespace

    from metrology.jobs.measure_report import MeasureReport

    counts = SimpleNamespace(fails=0, undecided=0, not_measured=0)
    result = SimpleNamespace(alarms=(), summary=SimpleNamespace(unknown_after=0, counts=lambda: counts))
    fake = MeasureReport(result, None, 0.5, 500.0, names, True, "one process", (), False, None, cv)
    return {c.name.split(":")[0]: c.value for c in fake.verdict.checks}
