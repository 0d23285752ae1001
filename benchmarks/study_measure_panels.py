"""Study (issue 36 item 4, the real panels): `metro measure --panel/--points` on the bundled CAD panels.

For each panel (flat, wing, concave barrel, nacelle, saddle) and each controller (the micro-plane's,
metro's normal in the loop): ``--seeds`` logs of ``--holes`` holes drilled by the forward simulator
(Table 6 head, its true layout the nominal: no calibration error), measured with the CAD panel and
its hole table. Reported: U95 coverage of the true angle before/after the adjustment, median U95,
median |measured - true angle|, median and p95 of the drilled hole's true angle.

    python benchmarks/study_measure_panels.py --seeds 2 --holes 200 --out benchmarks/results/measure_panels.json
"""

import argparse
import csv
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from typer.testing import CliRunner  # noqa: E402

from cli.main import app  # noqa: E402
from metrology.io.data import data_path  # noqa: E402

PANELS = ("flat", "wing", "barrel", "nacelle", "saddle")
TABLE6 = str(data_path("measured", "nominal.toml"))


def _read(p):
    with open(p, newline="") as fh:
        return list(csv.DictReader(fh))


def _f(rows, k):
    return np.array([float(r[k]) if r.get(k, "") != "" else np.nan for r in rows])


def run(kind, controller, seed, holes, tmp):
    r = CliRunner()
    pts = [] if kind == "flat" else ["--points", str(data_path("panels", f"{kind}.holes.csv"))]
    log = Path(tmp) / f"{kind}-{controller}-{seed}.csv"
    x = r.invoke(app, ["simulate-log", "--panel", kind, *pts, "--holes", str(holes), "--seed", str(seed),
                       "--layout", TABLE6, "--true-layout", TABLE6, "--controller", controller, "--out", str(log)])
    if x.exit_code != 0:
        return None
    out = log.with_suffix(".m.csv")
    panel = ["--min-radius-mm", "inf"] if kind == "flat" else ["--panel", str(data_path("panels", f"{kind}.stl"))]
    x = r.invoke(app, ["measure", str(log), "--layout", TABLE6, *panel, *pts, "--out", str(out), "--json"])
    assert x.exit_code in (0, 1), x.output
    m = _read(out)
    t = {q["hole_id"]: q for q in _read(log.with_name(log.stem + ".truth.csv"))}
    T = [t[q["hole_id"]] for q in m]
    return m, T


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--holes", type=int, default=200)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in PANELS:
            for controller in ("microplane", "metro"):
                acc = {k: [] for k in ("cb", "ca", "u", "e", "drilled")}
                for seed in range(1, a.seeds + 1):
                    got = run(kind, controller, seed, a.holes, tmp)
                    if got is None:
                        break
                    m, T = got
                    b, ub, tb = _f(m, "angle_deg"), _f(m, "U95_angle_deg"), _f(T, "true_angle_deg")
                    af, ua, ta = _f(m, "angle_after_deg"), _f(m, "U95_after_deg"), _f(T, "true_after_deg")
                    ok, oka = np.isfinite(b), np.isfinite(af)
                    acc["cb"] += list(np.abs(b[ok] - tb[ok]) <= ub[ok])
                    acc["ca"] += list(np.abs(af[oka] - ta[oka]) <= ua[oka])
                    acc["u"] += list(ub[ok])
                    acc["e"] += list(np.abs(b[ok] - tb[ok]))
                    acc["drilled"] += list(ta)
                if not acc["u"]:
                    rows.append({"panel": kind, "controller": controller, "ran": False})
                    continue
                rows.append({"panel": kind, "controller": controller, "ran": True, "holes": len(acc["drilled"]),
                             "coverage_before": float(np.mean(acc["cb"])), "coverage_after": float(np.mean(acc["ca"])),
                             "median_U95_deg": float(np.median(acc["u"])),
                             "median_angle_error_deg": float(np.median(acc["e"])),
                             "drilled_median_deg": float(np.nanmedian(acc["drilled"])),
                             "drilled_p95_deg": float(np.nanpercentile(acc["drilled"], 95))})
                r = rows[-1]
                print(f"| {kind} | {controller} | {r['holes']} | {100 * r['coverage_before']:.1f} % | "
                      f"{100 * r['coverage_after']:.1f} % | {r['median_U95_deg']:.4f}° | {r['median_angle_error_deg']:.4f}° | "
                      f"{r['drilled_median_deg']:.4f}° / {r['drilled_p95_deg']:.4f}° |", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps({"seeds": a.seeds, "holes": a.holes, "head": "Table 6 (nominal)",
                                           "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
