"""The reason column made column-wise (metrology.measure.reasons) reads as the per-row f-strings did."""

import numpy as np

from metrology.measure.batch import CODE, Status
from metrology.measure.reasons import fixed, reason_column, verdict_reasons


def test_fixed_reads_as_pythons_format_byte_for_byte():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(0, 5, 200_000), rng.exponential(1e-3, 20_000),
                        [0.0, -0.0, 5e-5, 1.5e-4, 2.5e-4, 1.23445, 2.5, 9.99995, 1e-20, 123456.78915, -1.5, 0.00015]])
    assert fixed(x).to_pylist() == [f"{v:.4f}" for v in x]
    assert fixed(x, 1).to_pylist() == [f"{v:.1f}" for v in x]


def test_verdict_reasons_are_the_per_row_templates():
    rng = np.random.default_rng(1)
    N = 5000
    code = rng.choice([CODE[s] for s in Status], N).astype(np.int8)
    after = rng.random(N) < 0.5
    judged, u = np.radians(rng.uniform(0, 1, N)), np.radians(rng.uniform(0.001, 0.1, N))
    tol = np.radians(0.5)
    got = verdict_reasons(code, after, judged, u, tol).to_pylist()
    for i in range(N):
        where = "after the adjustment" if after[i] else "as measured"
        if code[i] == CODE[Status.FAILS]:
            want = (f"{where}: angle {np.degrees(judged[i]):.4f} deg - U95 {np.degrees(u[i]):.4f} deg > tolerance "
                    f"{np.degrees(tol):g} deg")
        elif code[i] == CODE[Status.UNDECIDED]:
            want = (f"{where}: angle {np.degrees(judged[i]):.4f} deg +- U95 {np.degrees(u[i]):.4f} deg straddles the "
                    f"tolerance {np.degrees(tol):g} deg")
        else:
            want = ""
        assert got[i] == want, i
    # every hole one status: the same texts
    fails = np.full(N, CODE[Status.FAILS], np.int8)
    one = verdict_reasons(fails, np.zeros(N, bool), judged, u, tol).to_pylist()
    assert one[0].startswith("as measured: angle ") and one[0].endswith(f"> tolerance {np.degrees(tol):g} deg")


def test_notes_go_before_the_verdict():
    import pyarrow as pa

    verdict = pa.array(["", "as measured: x", "", "after: y"], pa.string())
    col = reason_column(verdict, {0: "a note", 3: "another"}).to_pylist()
    assert col == ["a note", "as measured: x", "", "another; after: y"]
    assert reason_column(verdict, {}).to_pylist() == verdict.to_pylist()
