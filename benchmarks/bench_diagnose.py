"""Speed of ``metro diagnose`` against ``metro calibrate`` on the same files, measured in the same run.

    python benchmarks/bench_diagnose.py [--repeat 3] [--export F --plane P --layout L]

Default files: the bundled measured set (``metrology/data/measured/``: 100 poses, 4 sensors,
its datum cloud as the plane). In this process, after one warm-up of each, the two jobs run in
turn ``--repeat`` times (so that load from other processes on the machine hits them alike):
:func:`metrology.jobs.calibrate.calibrate_files` (what ``metro calibrate`` runs) and
:func:`metrology.jobs.diagnose.diagnose_files` (what ``metro diagnose`` runs), both loading the
files (the diagnosis' kept fits, :func:`metrology.diagnosis.fit.memoised`, forgotten before each run, as a
fresh process starts). Then the same as whole processes (``metro calibrate ... --json`` and ``metro diagnose ...
--json``, imports included: what a user waits for). Printed: the best and median wall time of
each and the ratio of the medians (the issue's goal: ``diagnose / calibrate <= 1.5``).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

import _one_blas_thread  # noqa: F401  (first: one BLAS thread; same directory)

DATA = Path(__file__).resolve().parents[1] / "metrology" / "data" / "measured"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--export", default=str(DATA / "calibration.csv"))
    ap.add_argument("--plane", default=str(DATA / "datum.ply"))
    ap.add_argument("--layout", default=str(DATA / "nominal.toml"))
    a = ap.parse_args(argv)
    from metrology.jobs.calibrate import calibrate_files
    from metrology.jobs.diagnose import diagnose_files

    # each diagnosis starts with no fit kept (``diagnose`` forgets the run before's): as a fresh process
    jobs = {"calibrate": lambda: calibrate_files(a.export, a.plane, a.layout),
            "diagnose": lambda: diagnose_files(a.export, a.plane, a.layout)}
    times = {k: [] for k in jobs}
    for f in jobs.values():  # warm-up: imports, caches
        f()
    for _ in range(a.repeat):
        for k, f in jobs.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    _print("in process", times)
    metro = str(Path(sys.executable).parent / "metro")
    files = [a.export, "--plane", a.plane, "--layout", a.layout, "--json"]
    procs = {"calibrate": [metro, "calibrate", *files], "diagnose": [metro, "diagnose", *files]}
    times = {k: [] for k in procs}
    for _ in range(a.repeat):
        for k, cmd in procs.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times[k].append(time.perf_counter() - t0)
    _print("whole processes", times)


def _print(what, times):
    print(what)
    for k, ts in times.items():
        print(f"  {k:10s} best {min(ts):7.2f} s  median {statistics.median(ts):7.2f} s  ({len(ts)} runs)")
    ratio = statistics.median(times["diagnose"]) / statistics.median(times["calibrate"])
    print(f"  diagnose / calibrate (medians): {ratio:.2f}")


if __name__ == "__main__":
    main()
