"""Rule 3b's holes (metrology.measure.holes): undecided for a cause no verdict text names, so their reason is
their note alone; said by an explicit mask to ``verdict_reasons`` (``noted``), not by a stand-in status code.
Logs from the independent forward simulator."""

import numpy as np
import pyarrow as pa

from metrology.io.holelog import batch_of
from metrology.measure.batch import CODE
from metrology.measure.holes import Settings, Status, measure_batch
from metrology.measure.reasons import EDGE_TEXT, VERDICT_TEXTS, verdict_reasons
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_write import log_table
from metrology.sim.forward.panels import make_panel
from tests.measure.helpers import table6_cell_spec

TOL = np.radians(0.5)
#: rule 3b's note (metrology.measure.holes.measure_batch)
NOTE = "the failure is not shown"


def test_a_noted_hole_has_no_verdict_text_whatever_its_status_and_edge():
    code = np.array([CODE[s] for s in Status] * 4, np.int8)
    edge = np.tile(np.repeat([False, True], len(Status)), 2)
    noted = np.repeat([False, True], 2 * len(Status))
    after = np.arange(len(code)) % 3 == 0
    got = verdict_reasons(code, after, edge, noted=noted).to_pylist()
    plain = verdict_reasons(code, after, edge).to_pylist()
    assert all(t == "" for t, n in zip(got, noted) if n)
    assert [t for t, n in zip(got, noted) if not n] == [t for t, n in zip(plain, noted) if not n]
    assert any(t != "" for t, n in zip(plain, noted) if n)  # the mask, not the status, emptied them


def _log(holes, seed):
    spec = table6_cell_spec(make_panel("flat"), gross_rate=0.05)
    (chunk,) = list(simulate_cell(spec, seed, 0, holes, chunk_holes=holes))
    return spec.cell_layout, batch_of(log_table(chunk), spec.cell_layout.names)


def _reasons(b):
    return np.array([r or "" for r in b.columns.column("reason").to_pylist()], object)


def test_rule3b_holes_carry_their_note_alone_and_a_repeated_hole_its_own():
    layout, table = _log(2000, 5)
    b = measure_batch(layout, table, Settings(tolerance=TOL))
    reason = _reasons(b)
    unshown = np.flatnonzero([NOTE in r for r in reason])
    assert unshown.size  # the case is there
    assert np.all(b.status[unshown] == CODE[Status.UNDECIDED])
    texts = [t for pair in VERDICT_TEXTS.values() for t in pair]
    assert not any(r.endswith(t) or r.endswith(t + EDGE_TEXT) for r in reason[unshown] for t in texts)
    # a batch with rule 3b's holes and a repeated hole_id: the repeat is not measured, its reason its note alone
    # (the stand-in status code was a copy taken before the repeats were set: it gave them a verdict's text)
    ids = table.column("hole_id").to_pylist()
    failing = np.flatnonzero(b.status == CODE[Status.FAILS])
    first, repeat = int(failing[0]), int(failing[-1])
    ids[repeat] = ids[first]
    col = table.column_names.index("hole_id")
    b2 = measure_batch(layout, table.set_column(col, "hole_id", pa.array(ids, table.schema.field("hole_id").type)),
                       Settings(tolerance=TOL))
    r2 = _reasons(b2)
    assert b2.status[repeat] == CODE[Status.NOT_MEASURED]
    assert r2[repeat] == f"duplicate hole_id (row {first + 1} of this batch has it too)"
    assert np.array_equal(np.flatnonzero([NOTE in r for r in r2]), unshown)
