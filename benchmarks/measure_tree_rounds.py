"""Whole-process CPU (user + system) of the plain script, another tree's ``metro measure`` and this tree's, rounds
interleaved, every hole failing (``--tolerance-deg 0.1``) and conforming (``10``): the ratios of one round are the
figure on a shared machine (``bench_measure.py --sections verdicts`` measures this tree alone).

    git archive main | tar -x -C MAIN && python -m compileall -q MAIN/metrology MAIN/cli
    env -u PYTHONDONTWRITEBYTECODE python benchmarks/measure_tree_rounds.py MAIN WORKDIR ROUNDS OUT.json

WORKDIR holds ``log_before.parquet`` and ``calibrated.toml`` (``bench_measure.py --sections verdicts --workdir``
makes them). Each tree runs as ``python -c "sys.path.insert(0, TREE); cli.main.main()"``.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_measure import BASELINE, RUN, _ENV  # noqa: E402


def metro(tree):
    return [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(tree)!r}); from cli.main import main; "
                                  f"sys.argv[0] = 'metro'; sys.exit(main())"]


def cpu(cmd):
    r = subprocess.run([sys.executable, "-c", RUN, *cmd], capture_output=True, text=True, check=True, env=_ENV)
    _, _, rc, c = r.stdout.split()
    if int(rc) not in (0, 1):
        raise RuntimeError(f"{cmd} exited {rc}")
    return float(c)


def main():
    other, work, rounds, out = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    log, lay, res = work / "log_before.parquet", work / "calibrated.toml", work / "holes_rounds.parquet"
    cmds = {"plain": [sys.executable, "-c", BASELINE, str(log), str(lay), str(res)]}
    for tag, tree in (("main", other), ("new", HERE.parent)):
        for tol, what in (("0.1", "fail"), ("10", "conform")):
            cmds[f"{tag}_{what}"] = [*metro(tree), "-q", "measure", str(log), "--layout", str(lay), "--out", str(res),
                                     "--tolerance-deg", tol]
    for c in cmds.values():  # a warm-up: the bytecode written
        cpu(c)
    done = []
    for _ in range(rounds):
        load0 = os.getloadavg()[0]
        r = {k: cpu(c) for k, c in cmds.items()}
        r["load"] = (load0, os.getloadavg()[0])
        done.append(r)
        print(" ".join(f"{k} {v:.2f}" for k, v in r.items() if k != "load"), "| ratios main %.2f %.2f new %.2f %.2f" % tuple(
            r[k] / r["plain"] for k in ("main_fail", "main_conform", "new_fail", "new_conform")), flush=True)
    Path(out).write_text(json.dumps(done, indent=1))


if __name__ == "__main__":
    main()
