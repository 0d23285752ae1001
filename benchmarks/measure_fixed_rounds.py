"""The fixed costs of one ``metro measure`` process, two trees (or two installed ``metro``) interleaved: CPU
(user + system, ``os.wait4``) of ``metro measure`` refused at its first check (a log that does not exist: the
interpreter, typer, the command line's coercion and metro's CLI modules; nothing read) and on a log of 1000 holes
(every import and setup of a whole run), with the plain script on the same 1000 holes beside them.

    env -u PYTHONDONTWRITEBYTECODE python benchmarks/measure_fixed_rounds.py MAIN WORKDIR ROUNDS OUT.json [METRO]

MAIN and METRO as in ``measure_tree_rounds.py`` (a tree, or an installed ``metro``); WORKDIR holds
``log_before.parquet`` (its first 1000 rows are written to ``tiny.parquet`` here) and ``calibrated.toml``.
Each ratio's median comes with its 95 % bootstrap interval over the rounds (``bench_measure.interleaved``).
"""
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_measure import BASELINE, interleaved  # noqa: E402
from measure_tree_rounds import metro  # noqa: E402


def main():
    import pyarrow.parquet as pq

    other, work, rounds, out = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    mine = Path(sys.argv[5]) if len(sys.argv) > 5 else HERE.parent
    lay, tiny, res = work / "calibrated.toml", work / "tiny.parquet", work / "holes_tiny.parquet"
    pq.write_table(pq.read_table(work / "log_before.parquet").slice(0, 1000), tiny)
    cmds = {"plain_tiny": [sys.executable, "-c", BASELINE, str(tiny), str(lay), str(res)]}
    for tag, tree in (("main", other), ("new", mine)):
        cmds[f"{tag}_refused"] = [*metro(tree), "-q", "measure", str(work / "no-such-log.parquet"), "--layout",
                                  str(lay), "--out", str(res), "--tolerance-deg", "0.1"]
        cmds[f"{tag}_tiny"] = [*metro(tree), "-q", "measure", str(tiny), "--layout", str(lay), "--out", str(res),
                               "--tolerance-deg", "0.1"]
    ratios = {"refused_new_over_main": ("new_refused", "main_refused"), "tiny_new_over_main": ("new_tiny", "main_tiny"),
              "tiny_main_over_plain": ("main_tiny", "plain_tiny"), "tiny_new_over_plain": ("new_tiny", "plain_tiny")}
    done = interleaved(cmds, rounds, ratios, codes=(0, 1, 2))
    Path(out).write_text(json.dumps(done, indent=1))
    for c in cmds:
        print(f"{c}: median CPU {done['median_' + c + '_cpu_s']:.3f} s")
    for r in ratios:
        print(f"{r}: median {done['median_' + r]:.3f}, 95 % CI {done[r + '_median_ci95'][0]:.3f}-"
              f"{done[r + '_median_ci95'][1]:.3f}")
    print("load %.1f-%.1f" % tuple(done["load_range"]))


if __name__ == "__main__":
    main()
