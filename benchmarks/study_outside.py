"""Blind study of ``metro diagnose``'s open search (issue 54): effects outside the catalogue, and nulls.

Cases are drawn by :mod:`metrology.sim.forward` (the effects outside the catalogue by
:mod:`metrology.sim.forward.outside`, written from their physics before the search), written through
the public file contract and diagnosed by :func:`metrology.jobs.diagnose.diagnose_files`. Only the JSON
fields ``cause``, ``confidence``, ``causes`` and ``empirical`` are read.

Scores, per kind and overall:

- ``variable right``: the first empirical term is on the effect's sensor and names one of the
  effect's variables (``exact``: its variables are exactly the effect's);
- ``gain significant``: an empirical term on the effect's sensor with a held-out p below 0.05;
- ``catalogued high/moderate``: a catalogued cause named with confidence ``high`` or ``moderate``;
- nulls (``--nulls``, tracker and hand-probe scans alternately, 3 and 4 sensors alternately): an
  empirical term at all, with its 95 % Clopper-Pearson interval.

    python benchmarks/study_outside.py [--per-kind 10] [--nulls 100] [--seed 540] [--jobs 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time

import _one_blas_thread  # noqa: F401  (first: one BLAS thread a job; same directory)
import numpy as np


def jobs_for(per_kind: int, nulls: int, seed: int, kinds=None) -> list:
    """The cases: ``per_kind`` of each kind (of ``kinds`` only, if given: the same draws as in the full
    study, for development), then ``nulls``."""
    from metrology.sim.forward.outside import OUTSIDE_KINDS

    jobs = [("outside", k, (seed, 1, j, i)) for j, k in enumerate(OUTSIDE_KINDS) for i in range(per_kind)
            if not kinds or k in kinds]
    jobs += [("null", ("tracker", "hand")[i % 2], (seed, 0, i)) for i in range(nulls)]
    return jobs


def run_case(job) -> dict:
    from metrology.jobs.diagnose import diagnose_files
    from metrology.sim.forward import draw_case, draw_outside, write_case

    kind, what, entropy = job
    rng = np.random.default_rng(list(entropy))
    if kind == "outside":
        case = draw_outside(rng, what)
    else:
        n_sensors = 3 + (entropy[-1] // 2) % 2
        n_poses = int(np.random.default_rng(list(entropy) + [7]).integers(30, 151))
        case = draw_case(rng, "none", scan=what, n_sensors=n_sensors, n_poses=n_poses)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        paths = write_case(case, d)
        scan = paths["cloud.ply"]
        res = diagnose_files(paths["export.csv"], scan, paths["layout.toml"]).to_dict()
    rec = {"kind": kind, "what": what, "entropy": list(entropy), "n_sensors": case.nominal.n,
           "n_poses": case.export.n_poses, "seconds": time.perf_counter() - t0, "cause": res["cause"],
           "confidence": str(res["confidence"]),
           "causes": [(c["cause"], list(c.get("sensors") or [])) for c in res.get("causes") or []],
           "empirical": res.get("empirical")}
    if kind == "outside":
        e = case.effects[0]
        rec.update(sensor=e.sensors[0], variables=list(e.shape["variables"]), factor=e.shape["factor"],
                   size=e.size)
    return rec


def score(records) -> dict:
    from metrology.sim.forward import CATALOGUE

    out, by = {}, {}
    for r in records:
        if r["kind"] != "outside":
            continue
        terms = (r["empirical"] or {}).get("terms") or []
        first = terms[0] if terms else None
        truth = set(r["variables"])
        right = first is not None and first["sensor"] == r["sensor"] and bool(truth & set(first["variables"]))
        exact = first is not None and first["sensor"] == r["sensor"] and truth == set(first["variables"])
        sig = any(t["sensor"] == r["sensor"] and t["p_heldout"] < 0.05 for t in terms)
        cat = r["cause"] in CATALOGUE and r["confidence"] in ("high", "moderate")
        b = by.setdefault(r["what"], {"n": 0, "right": 0, "exact": 0, "gain": 0, "catalogued": 0})
        b["n"] += 1
        b["right"] += right
        b["exact"] += exact
        b["gain"] += sig
        b["catalogued"] += cat
    tot = {k: sum(b[k] for b in by.values()) for k in ("n", "right", "exact", "gain", "catalogued")}
    out["outside"] = {"by_kind": by, "all": tot}
    nulls = [r for r in records if r["kind"] == "null"]
    k = sum(bool((r["empirical"] or {}).get("terms")) for r in nulls)
    out["nulls"] = {"n": len(nulls), "empirical": k, "cp95": _cp(k, len(nulls)),
                    "by_scan": {s: sum(bool((r["empirical"] or {}).get("terms")) for r in nulls if r["what"] == s)
                                for s in ("tracker", "hand")},
                    "unexplained": sum(r["cause"] == "unexplained" for r in nulls),
                    "catalogued": sum(r["cause"] in CATALOGUE for r in nulls)}
    return out


def _cp(k, n, alpha=0.05):
    from scipy.stats import beta

    if n == 0:
        return [float("nan"), float("nan")]
    return [0.0 if k == 0 else float(beta.ppf(alpha / 2, k, n - k + 1)),
            1.0 if k == n else float(beta.ppf(1 - alpha / 2, k + 1, n - k))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-kind", type=int, default=10)
    ap.add_argument("--nulls", type=int, default=100)
    ap.add_argument("--seed", type=int, default=540)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", default=None)
    ap.add_argument("--kinds", default="", help="comma-separated kinds (development); all if empty")
    ap.add_argument("--interleave", action="store_true",
                    help="the same draws, each kind's first, then each kind's second, ...: a run stopped early "
                         "(the JSON is written after every case) has every kind alike")
    a = ap.parse_args(argv)
    jobs = jobs_for(a.per_kind, a.nulls, a.seed, [k for k in a.kinds.split(",") if k])
    if a.interleave:
        jobs = sorted(jobs, key=lambda j: (j[0] != "outside", j[2][-1], j[2][-2] if j[0] == "outside" else 0))
    t0 = time.time()
    records = []

    def keep(it):
        for r in it:
            records.append(r)
            print(json.dumps({k: r[k] for k in ("kind", "what", "entropy", "cause", "confidence")}
                             | {"terms": [(t["sensor"], t["term"]) for t in (r["empirical"] or {}).get("terms") or []],
                                "truth": (r.get("sensor"), r.get("variables"))}), flush=True)
            if a.json:
                with open(a.json, "w") as f:
                    json.dump({"args": vars(a), "records": records, "score": score(records),
                               "seconds": time.time() - t0}, f, indent=1)

    if a.jobs > 1:
        from multiprocessing import Pool

        with Pool(a.jobs) as pool:
            keep(pool.imap(run_case, jobs))
    else:
        keep(map(run_case, jobs))
    print(json.dumps(score(records), indent=1))
    print(f"{len(records)} cases in {time.time() - t0:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
