"""metro measure --follow holds its first lines for the units checks no longer than UNIT_WAIT_S: a client that sends
one line and waits for its answer gets it; the checks run again on the first UNIT_LINES lines when they come, and
a log in the wrong unit is still refused then (after the answers already given)."""

import csv
import io
import json
import os
import threading

from metrology.io.data import data_path
from metrology.jobs import measure_follow
from metrology.jobs.measure_follow import UNIT_LINES, follow_log
from tests.jobs.test_measure_follow_batches import lines  # noqa: F401 - the module's 40-hole log, a fixture

TABLE6 = str(data_path("measured", "nominal.toml"))


def _um(text):
    rows = list(csv.reader(text))
    cols = [i for i, c in enumerate(rows[0]) if c.startswith("d_")]
    for r in rows[1:]:
        for i in cols:
            r[i] = repr(float(r[i]) * 1000.0) if r[i] else r[i]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue().splitlines(keepends=True)


def _slow(text, monkeypatch):
    """Follow ``text`` (lines) through a pipe: the header and one hole, then (once that hole is answered, or after 60 s)
    the rest. (answers, error or None, whether the first hole was answered before the rest was sent)."""
    monkeypatch.setattr(measure_follow, "UNIT_WAIT_S", 0.3)
    r, w = os.pipe()
    first = threading.Event()
    answers = []

    def on_hole(h):
        answers.append(h)
        first.set()

    def write():
        with os.fdopen(w, "w") as fh:
            fh.write("".join(text[:2]))
            fh.flush()
            waited["alone"] = first.wait(60.0)
            fh.write("".join(text[2:]))

    waited = {}
    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    error = None
    with os.fdopen(r, "r", newline="") as stream:
        try:
            follow_log("-", TABLE6, on_hole, stream=stream)
        except ValueError as exc:
            error = str(exc)
    writer.join(60.0)
    return answers, error, waited["alone"]


def test_a_line_that_comes_alone_is_answered_before_the_next_is_sent(lines, monkeypatch):  # noqa: F811
    answers, error, alone = _slow(lines, monkeypatch)
    assert alone, "the first hole waited for the next lines"
    assert error is None and len(answers) == len(lines) - 1
    fast = []
    follow_log("-", TABLE6, fast.append, stream=io.StringIO("".join(lines)))
    assert json.dumps(answers) == json.dumps(fast)  # the same answers as a stream that came at once


def test_readings_in_um_are_refused_when_the_checked_lines_have_come(lines, monkeypatch):  # noqa: F811
    um = _um(lines)
    answers, error, alone = _slow(um, monkeypatch)
    assert alone and len(answers) == 1  # one hole cannot tell the unit (the reach rule needs UNIT_LINES)
    assert error is not None and "the readings look like µm" in error, error
    assert UNIT_LINES > 1
