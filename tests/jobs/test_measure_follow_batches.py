"""metro measure --follow measures the lines already read as one batch (issue 52): the answers are
those of one line at a time, whatever the batches (a repeated hole_id, a line in error)."""

import io
import json

import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.jobs.measure import MeasureOptions
from metrology.jobs.measure_follow import follow_log

runner = CliRunner()
TABLE6 = str(data_path("measured", "nominal.toml"))


@pytest.fixture(scope="module")
def lines(tmp_path_factory):
    log = tmp_path_factory.mktemp("follow") / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(log), "--holes", "40", "--seed", "52", "--layout", TABLE6,
                            "--true-layout", TABLE6, "--no-truth"])
    assert r.exit_code == 0, r.output
    return log.read_text().splitlines(keepends=True)


def _follow(text, max_batch, **options):
    out = []
    try:
        s = follow_log("-", TABLE6, lambda h: out.append(json.dumps(h)), lambda a: out.append(json.dumps(a)),
                       options=MeasureOptions(**options), stream=io.StringIO(text), max_batch=max_batch)
    except ValueError as exc:
        return out, str(exc)
    return out, s.to_dict()


def test_batches_answer_as_one_line_at_a_time(lines):
    text = list(lines)
    text[30] = text[10].replace(text[10].split(",")[1], text[30].split(",")[1], 1)  # hole 10's id again, in time
    text.insert(20, "\n")  # a blank line: skipped, the line numbers go on
    text = "".join(text)
    one, s1 = _follow(text, 1, tolerance_deg=0.3)
    many, s64 = _follow(text, 64, tolerance_deg=0.3)
    assert len(one) == 40 and one == many and s1 == s64
    repeated = [json.loads(h) for h in one if json.loads(h)["hole_id"] == json.loads(one[9])["hole_id"]]
    assert len(repeated) == 2 and "duplicate" not in repeated[1]["reason"]  # one line at a time: no batch to repeat in
    assert json.loads(one[-1])["line"] == 42


def test_a_line_in_error_mid_batch_stops_after_the_lines_before_it(lines):
    text = list(lines)
    text[32] = text[32].replace(",", ",x", 6)  # line 33: a reading that is not a number
    one, e1 = _follow("".join(text), 1)
    many, e64 = _follow("".join(text), 64)
    assert one == many and len(one) == 31 and e1 == e64
    assert "line 33" in e64 and "is not a number" in e64


def test_the_options_are_checked_as_measures_are(lines):
    with pytest.raises(ValueError, match="tolerance-deg"):
        follow_log("-", TABLE6, print, options=MeasureOptions(tolerance_deg=0.0), stream=io.StringIO("".join(lines)))


class _BadAt(io.StringIO):
    """A stream whose line ``at`` cannot be decoded (a byte not UTF-8 in a cell's live feed)."""

    def __init__(self, text, at):
        super().__init__(text)
        self.at, self.n = at, 0

    def readline(self, *a):
        self.n += 1
        if self.n == self.at:
            raise UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte")
        return super().readline(*a)


@pytest.mark.parametrize("max_batch", [1, 64])
def test_the_lines_before_a_read_error_are_answered_whatever_the_batch(lines, max_batch):
    out = []
    with pytest.raises(UnicodeDecodeError):
        follow_log("-", TABLE6, lambda h: out.append(h), None, options=MeasureOptions(),
                   stream=_BadAt("".join(lines), 34), max_batch=max_batch)
    assert [h["line"] for h in out] == list(range(2, 34))  # the header is line 1; line 34 unreadable
