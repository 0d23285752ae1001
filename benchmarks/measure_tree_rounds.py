"""Whole-process CPU (user + system) of the plain script, another tree's ``metro measure`` and this tree's, rounds
interleaved, every hole failing (``--tolerance-deg 0.1``) and conforming (``10``): the ratios of one round are the
figure on a shared machine (``bench_measure.py --sections verdicts`` measures this tree alone).

    git archive main | tar -x -C MAIN && python -m compileall -q MAIN/metrology MAIN/cli
    env -u PYTHONDONTWRITEBYTECODE python benchmarks/measure_tree_rounds.py MAIN WORKDIR ROUNDS OUT.json [METRO]

or, installed as a user installs them (clean venvs, ``uv pip install --compile-bytecode TREE``), each venv's
``metro`` executable for MAIN and METRO (this tree's side), run with the plain script under this Python.

WORKDIR holds ``log_before.parquet`` and ``calibrated.toml`` (``bench_measure.py --sections verdicts --workdir``
makes them). Each tree runs as ``python -c "sys.path.insert(0, TREE); cli.main.main()"``. Each process's CPU is
``os.wait4``'s rusage of it (``bench_measure.child_cpu``); the order of the commands is reversed every other round;
each ratio's median comes with its 95 % bootstrap interval over the rounds (``bench_measure.interleaved``).
"""
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_measure import BASELINE, interleaved  # noqa: E402


def metro(tree):
    if Path(tree).is_file():  # an installed ``metro``
        return [str(tree)]
    return [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(tree)!r}); from cli.main import main; "
                                  f"sys.argv[0] = 'metro'; sys.exit(main())"]


def main():
    other, work, rounds, out = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    log, lay, res = work / "log_before.parquet", work / "calibrated.toml", work / "holes_rounds.parquet"
    cmds = {"plain": [sys.executable, "-c", BASELINE, str(log), str(lay), str(res)]}
    mine = Path(sys.argv[5]) if len(sys.argv) > 5 else HERE.parent
    for tag, tree in (("main", other), ("new", mine)):
        for tol, what in (("0.1", "fail"), ("10", "conform")):
            cmds[f"{tag}_{what}"] = [*metro(tree), "-q", "measure", str(log), "--layout", str(lay), "--out", str(res),
                                     "--tolerance-deg", tol]
    ratios = {f"{c}_ratio": (c, "plain") for c in cmds if c != "plain"}
    ratios.update({f"{w}_new_over_main": (f"new_{w}", f"main_{w}") for w in ("fail", "conform")})
    done = interleaved(cmds, rounds, ratios)
    Path(out).write_text(json.dumps(done, indent=1))
    for r in ratios:
        print(f"{r}: median {done['median_' + r]:.3f}, 95 % CI {done[r + '_median_ci95'][0]:.3f}-"
              f"{done[r + '_median_ci95'][1]:.3f}, range {done[r + '_range'][0]:.2f}-{done[r + '_range'][1]:.2f}, "
              f"<= 1.2 in {done[r + '_rounds_at_or_below_1.2']} of {rounds}")
    print("load %.1f-%.1f" % tuple(done["load_range"]))


if __name__ == "__main__":
    main()
