"""``measure --panel --points`` against the same run without, for two source trees in turn (CPU seconds, user +
system, of each process): the speed of the panel path before and after a change, each ratio within one round.

    git archive main | tar -x -C OLD
    python benchmarks/measure_panel_trees.py ROUNDS OUT.json --tree main=OLD --tree branch=. --log bench=LOG.parquet \
        [--log wing500=W.parquet]

Each round runs, for each log and each tree (``python -m cli.main`` with ``PYTHONPATH`` the tree), ``metro -q measure
LOG --layout nominal.toml --out F`` without and with ``--panel wing.stl --points wing.holes.csv`` (the bundled wing).
The logs: ``bench_measure.py --sections panel``'s (``metro simulate-log --panel ... --holes 1e6 --seed 1``) and
``measure_rounds.py``'s ``wing500.parquet``. The load average before and after each round is kept; the outputs are
left in ``--outdir`` (``TREE_LOG_{plain,panel}.parquet``) to compare the trees' bytes.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
D = ROOT / "metrology" / "data"
PANEL = ["--panel", str(D / "panels" / "wing.stl"), "--points", str(D / "panels" / "wing.holes.csv")]


def cpu(cmd, env):
    """CPU seconds (user + system) of the child ``cmd``."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)}: exit {p.returncode}\n{p.stderr.decode()[-2000:]}")
    return r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("rounds", type=int)
    ap.add_argument("out")
    ap.add_argument("--tree", action="append", required=True, help="NAME=PATH of a source tree")
    ap.add_argument("--log", action="append", required=True, help="NAME=PATH of a hole log")
    ap.add_argument("--outdir", default=None, help="where the outputs go (default: beside OUT.json)")
    a = ap.parse_args()
    trees = dict(t.split("=", 1) for t in a.tree)
    logs = dict(x.split("=", 1) for x in a.log)
    outdir = Path(a.outdir or Path(a.out).parent / "panel_trees_out")
    outdir.mkdir(parents=True, exist_ok=True)
    res = []
    for _ in range(a.rounds):
        r = {"utc": time.strftime("%H:%M:%S", time.gmtime()), "load_before": os.getloadavg()[0]}
        for lname, log in logs.items():
            for tree, path in trees.items():
                env = dict(os.environ, PYTHONPATH=str(Path(path).resolve()))
                for p in ("plain", "panel"):
                    cmd = [sys.executable, "-m", "cli.main", "-q", "measure", log, "--layout",
                           str(D / "measured" / "nominal.toml"), "--out", str(outdir / f"{tree}_{lname}_{p}.parquet"),
                           *(PANEL if p == "panel" else [])]
                    r[f"{lname}_{tree}_{p}_cpu_s"] = cpu(cmd, env)
                r[f"{lname}_{tree}_ratio"] = r[f"{lname}_{tree}_panel_cpu_s"] / r[f"{lname}_{tree}_plain_cpu_s"]
        r["load_after"] = os.getloadavg()[0]
        res.append(r)
        print(json.dumps(r), flush=True)
        Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
