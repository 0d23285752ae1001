"""``measure_batch``'s CPU on this tree and on another commit's, in one process, passes alternated (a shared machine's
load falls on both alike; the whole-process ratios are ``bench_measure.py --sections verdicts``'s).

    python benchmarks/measure_batch_ab.py REF LOG.parquet LAYOUT.toml [--rounds 8]

REF's ``metrology/`` is extracted (``git archive``) into a temporary folder as the package ``metrology_ref`` (its
imports renamed), so both load side by side; each round measures every batch of LOG (read once, as ``metro measure``
reads it) with every hole failing (``--tolerance-deg 0.1``) and conforming (``10``), REF first in even rounds.
Prints each side's min and median CPU seconds per pass and the per-round ratio (this tree / REF).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def extract(ref: str, into: Path) -> None:
    """REF's ``metrology`` package as ``into/metrology_ref``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "metrology"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "metrology").rename(into / "metrology_ref")
    for p in (into / "metrology_ref").rglob("*.py"):
        p.write_text(re.sub(r"\bmetrology\.", "metrology_ref.", p.read_text()).replace("from metrology import",
                                                                                         "from metrology_ref import"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("ref"); ap.add_argument("log"); ap.add_argument("layout")
    ap.add_argument("--rounds", type=int, default=8)
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    extract(a.ref, tmp)
    sys.path[:0] = [str(ROOT), str(tmp)]
    import numpy as np

    import metrology.measure.holes as this
    import metrology_ref.io.layout as ref_layout
    import metrology_ref.measure.holes as ref
    from metrology.io.holelog import open_log
    from metrology.io.layout import load_layout
    from metrology.measure.run import tune_allocator

    tune_allocator()
    lay, lay_ref = load_layout(a.layout), ref_layout.load_layout(a.layout)
    log = open_log(a.log, lay.names)
    tables = [t for part in log.partitions for t, _ in log.batches(part)]
    res = {}
    for tol in (0.1, 10.0):
        for r in range(a.rounds):
            sides = (("ref", ref, lay_ref), ("this", this, lay))
            for tag, mod, L in sides if r % 2 == 0 else sides[::-1]:
                settings = mod.Settings(tolerance=float(np.radians(tol)))
                t0 = time.process_time()
                for t in tables:
                    mod.measure_batch(L, t, settings)
                res.setdefault((tol, tag), []).append(time.process_time() - t0)
        ratio = np.array(res[(tol, "this")]) / np.array(res[(tol, "ref")])
        print(f"--tolerance-deg {tol:g}: {a.ref} min {min(res[(tol, 'ref')]):.3f} median {np.median(res[(tol, 'ref')]):.3f} s;"
              f" this tree min {min(res[(tol, 'this')]):.3f} median {np.median(res[(tol, 'this')]):.3f} s;"
              f" this / {a.ref} per round median {np.median(ratio):.3f} ({ratio.min():.3f}-{ratio.max():.3f})")


if __name__ == "__main__":
    main()
