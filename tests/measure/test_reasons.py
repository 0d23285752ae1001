"""The reason column made column-wise (metrology.measure.reasons): one fixed text per cause, no per-row numbers."""

import numpy as np

from metrology.measure.batch import CODE, Status
from metrology.measure.reasons import VERDICT_TEXTS, reason_column, verdict_reasons


def test_verdict_reasons_are_one_text_per_status_and_judgement():
    rng = np.random.default_rng(1)
    N = 5000
    code = rng.choice([CODE[s] for s in Status], N).astype(np.int8)
    after = rng.random(N) < 0.5
    got = verdict_reasons(code, after).to_pylist()
    for i in range(N):
        where = "after the adjustment" if after[i] else "as measured"
        if code[i] == CODE[Status.FAILS]:
            want = f"{where}: angle - U95 > tolerance"
        elif code[i] == CODE[Status.UNDECIDED]:
            want = f"{where}: angle +- U95 straddles the tolerance"
        else:
            want = ""
        assert got[i] == want, i
    assert len(set(got)) == 5  # "" and the four texts: a dictionary of five values
    assert all(not any(ch.isdigit() for ch in t.replace("U95", "")) for pair in VERDICT_TEXTS.values() for t in pair)


def test_every_hole_one_status():
    N = 1000
    fails = np.full(N, CODE[Status.FAILS], np.int8)
    assert set(verdict_reasons(fails, np.zeros(N, bool)).to_pylist()) == {"as measured: angle - U95 > tolerance"}
    conforms = np.full(N, CODE[Status.CONFORMS], np.int8)
    col = verdict_reasons(conforms, np.ones(N, bool))
    assert col.null_count == 0 and set(col.to_pylist()) == {""}


def test_notes_go_before_the_verdict():
    import pyarrow as pa

    verdict = pa.array(["", "as measured: x", "", "after: y"], pa.string())
    col = reason_column(verdict, {0: "a note", 3: "another"}).to_pylist()
    assert col == ["a note", "as measured: x", "", "another; after: y"]
    assert reason_column(verdict, {}).to_pylist() == verdict.to_pylist()
