"""Does ``angle +- U95`` of ``metro measure --panel --points`` hold the true angle on logs whose head spins
freely about the tool axis and that carry no pose (issue 49)?

For each bundled panel (``--panels``) and head (the Table 6 square of 4 sensors, and its first 3), a log is
drawn by the independent forward simulator (``metro simulate-log --spin-deg SPIN``: the head's spin uniform
within +-SPIN; 180 is a free spin), its ``pose_*`` columns dropped, and measured with the panel and its hole
table, ``--spin-deg`` not given (and given, ``--stated``). Per row: holes, holes judged with the spin in the
convention / over every spin, coverage of the true angle (before and after the adjustment), median U95 and
median |error| (deg).

    python benchmarks/study_spin.py --holes 2000 --spin 180 --seed 21 [--panels wing,barrel] [--json F]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def run(panel: str, n_sensors: int, spin_deg: float, holes: int, seed: int, work: Path, stated: float | None):
    import pyarrow.parquet as pq

    from metrology.io.layout import load_layout, save_layout
    from metrology.jobs.measure_panel import hole_surfaces
    from metrology.measure.holes import Settings, measure_batch

    data = ROOT / "metrology" / "data"
    layout = data / "measured" / "nominal.toml"
    if n_sensors == 3:
        lay3 = work / "nominal3.toml"
        save_layout(load_layout(layout).subset(("L1", "L2", "L3")), lay3)
        layout = lay3
    log = work / f"{panel}{n_sensors}_{seed}.parquet"
    stl, pts = data / "panels" / f"{panel}.stl", data / "panels" / f"{panel}.holes.csv"
    if not log.exists():
        subprocess.run([sys.executable, "-m", "cli.main", "simulate-log", "--out", str(log), "--holes", str(holes),
                        "--seed", str(seed), "--panel", str(stl), "--points", str(pts), "--true-layout", str(layout),
                        "--layout", str(layout), "--spin-deg", str(spin_deg)], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL)
    t = pq.read_table(log)
    t = t.drop_columns([c for c in t.column_names if c.startswith("pose_")])
    truth = pq.read_table(log.with_name(log.stem + ".truth.parquet"))
    lay = load_layout(layout)
    surf = hole_surfaces(lay, stl, pts, 0.5, 0.0, stated)
    b = measure_batch(lay, t, Settings(surfaces=surf))
    tt = {k: truth.column(k).to_numpy(zero_copy_only=False).astype(float) for k in ("true_angle_deg", "true_after_deg")}
    ids = truth.column("hole_id").to_pylist()
    order = {h: i for i, h in enumerate(ids)}
    idx = np.array([order[h] for h in t.column("hole_id").to_pylist()])
    out = {"panel": panel, "sensors": n_sensors, "spin_deg": spin_deg, "stated_deg": stated, "holes": len(t),
           "on_convention": int(b.on_convention.sum()), "spin_free": int(b.spin_free.sum())}
    for key, col, u in (("before", "angle_deg", "U95_angle_deg"), ("after", "angle_after_deg", "U95_after_deg")):
        a = b.columns.column(col).to_numpy(zero_copy_only=False).astype(float)
        U = b.columns.column(u).to_numpy(zero_copy_only=False).astype(float)
        true = tt["true_angle_deg" if key == "before" else "true_after_deg"][idx]
        ok = np.isfinite(a) & np.isfinite(U) & np.isfinite(true)
        err = np.abs(a - true)[ok]
        out[key] = {"measured": int(ok.sum()), "coverage": float(np.mean(err <= U[ok])) if ok.any() else None,
                    "median_U95_deg": float(np.median(U[ok])) if ok.any() else None,
                    "median_err_deg": float(np.median(err)) if ok.any() else None,
                    "coverage_convention": float(np.mean((err <= U[ok])[b.on_convention[ok]]))
                    if b.on_convention[ok].any() else None,
                    "coverage_free": float(np.mean((err <= U[ok])[b.spin_free[ok]])) if b.spin_free[ok].any() else None}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--holes", type=int, default=2000)
    ap.add_argument("--spin", type=float, default=180.0)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--panels", default="wing,barrel")
    ap.add_argument("--stated", type=float, default=None, help="also measure with --spin-deg STATED")
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    work = args.workdir or Path(tempfile.mkdtemp(prefix="study-spin-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for panel in args.panels.split(","):
        for n in (4, 3):
            for stated in (None,) if args.stated is None else (None, args.stated):
                r = run(panel, n, args.spin, args.holes, args.seed, work, stated)
                rows.append(r)
                print(json.dumps(r), flush=True)
    print("| panel | sensors | spin | --spin-deg | holes | on convention | over every spin | coverage before | "
          "coverage after | median U95 after [deg] | median error after [deg] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        f = (lambda v: "-" if v is None else f"{100 * v:.1f} %")
        g = (lambda v: "-" if v is None else f"{v:.4f}")
        print(f"| {r['panel']} | {r['sensors']} | +-{r['spin_deg']:g} | {r['stated_deg'] or '-'} | {r['holes']} | "
              f"{r['on_convention']} | {r['spin_free']} | {f(r['before']['coverage'])} | {f(r['after']['coverage'])} | "
              f"{g(r['after']['median_U95_deg'])} | {g(r['after']['median_err_deg'])} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
