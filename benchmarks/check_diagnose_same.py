"""Whether two trees' ``metro diagnose`` give the same verdicts and numbers on a fixed set of cases.

    PYTHONPATH=TREE_A python benchmarks/check_diagnose_same.py run --out a.json
    PYTHONPATH=TREE_B python benchmarks/check_diagnose_same.py run --out b.json
    python benchmarks/check_diagnose_same.py compare a.json b.json [--rtol 1e-9]

A speed change of the diagnosis must not change what it says. ``run`` diagnoses the cases below
through the public file contract (``write_case`` -> ``diagnose_files``, what ``metro diagnose``
calls) with the tree first on ``PYTHONPATH`` and writes each case's whole ``--json`` result
(``Diagnosis.to_dict``) and its CPU seconds. ``compare`` walks the two results: every string,
boolean, integer and list length equal, and every float equal or within ``--rtol`` relative
(``--atol`` absolute near zero); it prints the verdicts, how many floats were bit-equal, the
largest relative difference, and the CPU of each side; exit 1 on any difference beyond them.

The cases (29): the blind study's draws at seed 5512 (:mod:`study_blind`: 4 nulls, one draw of
each family and of the two out-of-catalogue ones, 6 pairs, 2 nulls with the scan tilted), the
cases of ``tests/diagnosis/test_datum_plane_given.py`` (a pose error's spread, a drift beside a
tilted hand-probe scan, a knock with an incidence bias and gross readings), a plane form and a
two-sensor drift on a 3-sensor head, and the bundled measured set (``metrology/data/measured``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SEED = 5512


def cases() -> list:
    """``[(name, make)]``: ``make()`` returns the forward-simulated Case, or None for the bundled set."""
    sys.path.insert(0, str(HERE))
    import study_blind as sb
    from metrology.sim.forward import draw_case, draw_pair
    from metrology.sim.forward.cases import _draw

    out = []
    jobs = sb.jobs_for(draws=1, nulls=4, pairs=6, seed=SEED, tilts=2)
    for kind, fams, entropy in jobs:
        def make(kind=kind, fams=fams, entropy=entropy):
            rng = np.random.default_rng(list(entropy))
            if kind == "datum":
                return sb.tilt_scan(draw_case(rng, "none"), rng)[0]
            return draw_pair(rng, *fams) if kind == "pair" else draw_case(rng, fams[0])
        out.append((f"{kind}:{'+'.join(fams)}:{'-'.join(map(str, entropy))}", make))

    def spread():
        return draw_case(np.random.default_rng([1, 54, 1, 2]), "pose_error", size=0.04, cloud_noise_mm=0.0005)

    def headline():
        rng = np.random.default_rng([54, 18, 0])
        return sb.tilt_scan(draw_case(rng, "drift", size=0.08, scan="hand", n_poses=60), rng)[0]

    def knock():
        return _draw(np.random.default_rng([4040, 54, 0, 3]), ["shift", "incidence", "outliers"], [None] * 3,
                     n_sensors=None, noise_mm=None, n_poses=None, tilt_max_deg=14.0, range_mm=(30.0, 70.0),
                     n_cloud=2000, cloud_noise_mm=0.010, blanks=None)

    def form3():
        return draw_case(np.random.default_rng([7, 51, 6]), "plane_form", n_sensors=3, n_poses=70)

    def drift2():
        return draw_pair(np.random.default_rng([7, 51, 7]), "drift", "drift", n_sensors=3)

    out += [("test:pose_error_spread", spread), ("test:headline_drift_hand_tilt", headline),
            ("test:knock_incidence_outliers", knock), ("extra:plane_form_3", form3), ("extra:drift_drift_3", drift2),
            ("bundled:measured", lambda: None)]
    return out


def run(out_path, only=None):
    import metrology
    from metrology.jobs.diagnose import diagnose_files
    from metrology.sim.forward import write_case

    data = Path(metrology.__file__).resolve().parent / "data" / "measured"
    results = {"tree": str(Path(metrology.__file__).resolve().parents[1]), "cases": {}}
    print("tree:", results["tree"], flush=True)
    for name, make in cases():
        if only and not any(o in name for o in only):
            continue
        case = make()
        with tempfile.TemporaryDirectory() as d:
            if case is None:
                files = (data / "calibration.csv", data / "datum.ply", data / "nominal.toml")
            else:
                paths = write_case(case, d)
                files = (paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
            t0 = time.process_time()
            try:
                res = diagnose_files(*files).to_dict()
            except ValueError as e:
                res = {"refused": str(e)}
            cpu = time.process_time() - t0
        results["cases"][name] = {"cpu_s": cpu, "result": json.loads(json.dumps(res, default=_plain))}
        print(f"{cpu:6.2f} s  {name}: {res.get('cause')} {res.get('sensors')} {res.get('confidence')}", flush=True)
    Path(out_path).write_text(json.dumps(results))


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    return str(v)


def _walk(a, b, path, stats, rtol, atol):
    """Differences of ``a`` and ``b`` beyond the tolerances, as ``[(path, a, b)]``; ``stats`` counts floats."""
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None or isinstance(a, str):
        return [] if a == b else [(path, a, b)]
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if isinstance(a, int) and isinstance(b, int):
            return [] if a == b else [(path, a, b)]
        fa, fb = float(a), float(b)
        stats["floats"] += 1
        if fa == fb or (math.isnan(fa) and math.isnan(fb)):
            stats["equal"] += 1
            return []
        if math.isnan(fa) or math.isnan(fb) or math.isinf(fa) or math.isinf(fb):
            return [(path, a, b)]
        rel = abs(fa - fb) / max(abs(fa), abs(fb))
        if rel > stats["max_rel"]:
            stats["max_rel"], stats["max_at"] = rel, path
        return [] if abs(fa - fb) <= max(rtol * max(abs(fa), abs(fb)), atol) else [(path, a, b)]
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [(path + ".keys", sorted(a), sorted(b))]
        return [d for k in a for d in _walk(a[k], b[k], f"{path}.{k}", stats, rtol, atol)]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [(path + ".len", len(a), len(b))]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _walk(x, y, f"{path}[{i}]", stats, rtol, atol)]
    return [(path, a, b)]


def compare(pa, pb, rtol, atol) -> int:
    A, B = json.loads(Path(pa).read_text()), json.loads(Path(pb).read_text())
    print("A:", A["tree"], " B:", B["tree"])
    bad, cpu_a, cpu_b = 0, 0.0, 0.0
    total = {"floats": 0, "equal": 0, "max_rel": 0.0, "max_at": ""}
    for name in A["cases"]:
        if name not in B["cases"]:
            continue
        ra, rb = A["cases"][name]["result"], B["cases"][name]["result"]
        stats = {"floats": 0, "equal": 0, "max_rel": 0.0, "max_at": ""}
        diffs = _walk(ra, rb, "", stats, rtol, atol)
        ca, cb = A["cases"][name]["cpu_s"], B["cases"][name]["cpu_s"]
        cpu_a, cpu_b = cpu_a + ca, cpu_b + cb
        verdict = f"{ra.get('cause')} {ra.get('sensors')} {ra.get('confidence')}"
        same = "same" if not diffs else f"{len(diffs)} DIFFER"
        print(f"{ca:6.2f} {cb:6.2f} s  {name}: {verdict}; {stats['equal']}/{stats['floats']} floats bit-equal, "
              f"max rel {stats['max_rel']:.1e}; {same}")
        for d in diffs[:5]:
            print("     ", d)
        bad += bool(diffs)
        total["floats"] += stats["floats"]
        total["equal"] += stats["equal"]
        if stats["max_rel"] > total["max_rel"]:
            total["max_rel"], total["max_at"] = stats["max_rel"], f"{name}{stats['max_at']}"
    n = len([k for k in A["cases"] if k in B["cases"]])
    print(f"{n} cases, {bad} differ beyond rtol {rtol:g} (atol {atol:g}); floats bit-equal {total['equal']} of "
          f"{total['floats']}; largest relative difference {total['max_rel']:.2e} at {total['max_at']}")
    print(f"CPU s: A {cpu_a:.1f}, B {cpu_b:.1f} (B/A {cpu_b / max(cpu_a, 1e-9):.3f})")
    return 1 if bad else 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--out", required=True)
    r.add_argument("--only", nargs="*", help="run the cases whose name contains one of these")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    c.add_argument("--rtol", type=float, default=1e-9)
    c.add_argument("--atol", type=float, default=1e-12)
    a = ap.parse_args(argv)
    if a.cmd == "run":
        run(a.out, a.only)
        return 0
    return compare(a.a, a.b, a.rtol, a.atol)


if __name__ == "__main__":
    sys.exit(main())
